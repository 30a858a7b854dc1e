"""Real infrastructure for the service tests, started and stopped by fixtures.

* PostgreSQL: a fresh database ``firefly3d_test_<random>`` per test session, migrated
  with ``alembic upgrade head`` and dropped at the end (parallel runs never collide).
* Redis: the machine's server; every broker key carries a per-session prefix.
* S3: moto's standalone server on a free port, reached through the production boto3 code.
* Celery: real ``firefly3d worker`` subprocesses with the test settings in their
  environment (see `WorkerProcess`), SIGKILL-able.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import boto3
import psycopg
import pytest
import redis
from alembic import command
from alembic.config import Config
from fastapi.testclient import TestClient
from moto.server import ThreadedMotoServer

from services.api.app import create_app
from services.core.db import SessionFactory, make_engine, make_session_factory
from services.core.settings import Settings
from tests.services.helpers import NIGHT, TEST_ADMIN_TOKEN, TEST_PARAMS

ROOT = Path(__file__).resolve().parents[2]
POSTGRES = os.environ.get("FIREFLY3D_TEST_POSTGRES", "postgresql://postgres@127.0.0.1:5432")
REDIS = os.environ.get("FIREFLY3D_TEST_REDIS", "redis://127.0.0.1:6379/0")
RABBITMQ = os.environ.get("FIREFLY3D_TEST_RABBITMQ", "amqp://guest:guest@127.0.0.1:5672//")
BUCKET = "firefly3d-test"
#: Lifetime of download links in the tests: pages must work past it.
LINK_LIFETIME_S = 3


# moto's server logs every request at INFO: keep failure reports readable.
logging.getLogger("werkzeug").setLevel(logging.WARNING)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def alembic_config(url: str) -> Config:
    config = Config(str(ROOT / "alembic.ini"))
    config.set_main_option("sqlalchemy.url", url)
    config.attributes["configure_logger"] = False
    return config


def create_database(prefix: str = "firefly3d_test") -> str:
    """A new empty database; returns its SQLAlchemy URL."""
    name = f"{prefix}_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(f"{POSTGRES}/postgres", autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    return f"{POSTGRES.replace('postgresql://', 'postgresql+psycopg://')}/{name}"


def drop_database(url: str) -> None:
    name = url.rsplit("/", 1)[1]
    with psycopg.connect(f"{POSTGRES}/postgres", autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture(scope="session")
def database_url() -> Iterator[str]:
    url = create_database()
    command.upgrade(alembic_config(url), "head")
    yield url
    drop_database(url)


@pytest.fixture(scope="session")
def sessions(database_url: str) -> Iterator[SessionFactory]:
    engine = make_engine(database_url)
    yield make_session_factory(engine)
    engine.dispose()


@pytest.fixture(scope="session")
def broker_prefix() -> Iterator[str]:
    prefix = f"firefly3d-test-{uuid.uuid4().hex[:8]}:"
    yield prefix
    client = redis.Redis.from_url(REDIS)
    for key in client.scan_iter(match=f"{prefix}*", count=1000):
        client.delete(key)
    client.close()


@pytest.fixture(scope="session")
def s3_endpoint() -> Iterator[str]:
    port = free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    endpoint = f"http://127.0.0.1:{port}"
    boto3.client(
        "s3",
        endpoint_url=endpoint,
        region_name="us-east-1",
        aws_access_key_id="test",
        aws_secret_access_key="test",
    ).create_bucket(Bucket=BUCKET)
    yield endpoint
    server.stop()


def settings_env(settings: Settings) -> dict[str, str]:
    """The ``FIREFLY3D_*`` variables that reproduce `settings` in a subprocess."""
    env = {}
    for name, value in settings.model_dump(mode="json").items():
        if value is None:
            continue
        secret = getattr(settings, name)
        raw = secret.get_secret_value() if hasattr(secret, "get_secret_value") else value
        env[f"FIREFLY3D_{name.upper()}"] = str(raw)
    return env


def make_settings(
    database_url: str,
    broker_prefix: str,
    tmp: Path,
    *,
    backend: str,
    s3_endpoint: str | None = None,
    **overrides: object,
) -> Settings:
    """Test settings: small limits so that faults show up in seconds, not hours."""
    values: dict[str, object] = {
        "database_url": database_url,
        "broker_url": REDIS,
        "broker_key_prefix": broker_prefix,
        "queue": f"q-{uuid.uuid4().hex[:8]}",
        "storage_backend": backend,
        "local_storage_dir": tmp / "storage",
        "s3_endpoint_url": s3_endpoint,
        "s3_bucket": BUCKET,
        "s3_access_key_id": "test",
        "s3_secret_access_key": "test",
        "admin_token": TEST_ADMIN_TOKEN,
        "secret_key": "test-secret",
        "work_dir": tmp / "work",
        "task_soft_time_limit_s": 120,
        "task_time_limit_s": 150,
        "visibility_timeout_s": 180,
        "unacked_restore_interval_s": 2,
        "retry_backoff_s": 0.5,
        "progress_interval_s": 0.2,
        "heartbeat_interval_s": 1.0,
        "stall_limit_s": 30.0,
        "sweep_interval_s": 2.0,
        # Tests of access control send many bad tokens from one address.
        "auth_failures_limit": 10_000,
        "min_part_bytes": 5 << 20,
        "download_url_expires_s": LINK_LIFETIME_S,
        **overrides,
    }
    return Settings.model_validate(values)


class WorkerProcess:
    """A ``firefly3d worker`` subprocess in its own process group."""

    def __init__(self, settings: Settings, log: Path, name: str) -> None:
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("FIREFLY3D_")}
        self.env |= settings_env(settings)
        self.log, self.name = log, name
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self, timeout: float = 90.0) -> WorkerProcess:
        firefly3d = Path(sys.executable).with_name("firefly3d")
        offset = self.log.stat().st_size if self.log.exists() else 0
        with self.log.open("ab") as out:
            self.proc = subprocess.Popen(
                [str(firefly3d), "worker", "--concurrency", "2", "--hostname", f"{self.name}@%h"],
                env=self.env,
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                cwd=ROOT,
            )
        deadline = time.monotonic() + timeout
        while b" ready." not in self.log.read_bytes()[offset:]:
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"worker did not start:\n{self.log.read_text()[-4000:]}")
            time.sleep(0.2)
        return self

    def kill(self) -> None:
        """SIGKILL the worker and its pool processes, as a machine failure would."""
        assert self.proc is not None
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()

    def stop(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        os.killpg(self.proc.pid, signal.SIGTERM)
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.kill()


class Service:
    """An API (in-process `TestClient`) and its settings, sharing the real infrastructure."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.app = create_app(settings)
        self.client = TestClient(self.app)
        self.sessions: SessionFactory = self.app.state.sessions
        self.storage = self.app.state.storage


@pytest.fixture(scope="session")
def s3_settings(
    database_url: str,
    broker_prefix: str,
    s3_endpoint: str,
    tmp_path_factory: pytest.TempPathFactory,
) -> Settings:
    tmp = tmp_path_factory.mktemp("s3-service")
    return make_settings(database_url, broker_prefix, tmp, backend="s3", s3_endpoint=s3_endpoint)


@pytest.fixture(scope="session")
def local_settings(
    database_url: str, broker_prefix: str, tmp_path_factory: pytest.TempPathFactory
) -> Settings:
    return make_settings(
        database_url, broker_prefix, tmp_path_factory.mktemp("local-service"), backend="local"
    )


@pytest.fixture(scope="session")
def s3_service(s3_settings: Settings) -> Iterator[Service]:
    service = Service(s3_settings)
    yield service
    service.client.close()


@pytest.fixture(scope="session")
def local_service(local_settings: Settings) -> Iterator[Service]:
    service = Service(local_settings)
    yield service
    service.client.close()


@pytest.fixture(scope="session")
def s3_worker(
    s3_settings: Settings, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[WorkerProcess]:
    worker = WorkerProcess(s3_settings, tmp_path_factory.mktemp("logs") / "s3-worker.log", "s3")
    yield worker.start()
    worker.stop()


@pytest.fixture(scope="session")
def local_worker(
    local_settings: Settings, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[WorkerProcess]:
    log = tmp_path_factory.mktemp("logs") / "local-worker.log"
    worker = WorkerProcess(local_settings, log, "local")
    yield worker.start()
    worker.stop()


@pytest.fixture(scope="session")
def recording(tmp_path_factory: pytest.TempPathFactory) -> dict[int, list[Path]]:
    """A simulated 20 s stereo recording, 640×320; camera 2 in two chapter files."""
    from pipeline.simulate import SimulationConfig, simulate

    out = tmp_path_factory.mktemp("recording")
    config = SimulationConfig(width=640, seconds=20, chapters=(1, 2), seed=3)
    recorded = simulate(config, out)
    return {1: list(recorded.cam1), 2: list(recorded.cam2)}


@pytest.fixture(scope="session")
def reference(recording: dict[int, list[Path]], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The result folder of ``firefly3d process`` on `recording` with the test parameters."""
    tmp = tmp_path_factory.mktemp("reference")
    params = tmp / "params.json"
    params.write_text(json.dumps(TEST_PARAMS))
    args = [str(Path(sys.executable).with_name("firefly3d")), "process", "--quiet"]
    args += [a for p in recording[1] for a in ("--cam1", str(p))]
    args += [a for p in recording[2] for a in ("--cam2", str(p))]
    args += ["--separation", str(NIGHT["separation_m"]), "--camera-height", str(NIGHT["height_m"])]
    # The night's clock as the service's night row gives it to the workers.
    for option in ("latitude", "longitude", "time_zone", "start_time"):
        args += [f"--{option.replace('_', '-')}", str(NIGHT[option])]
    args += ["--params", str(params), "--out", str(tmp / "out")]
    result = subprocess.run(args, capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    return tmp / "out"


@pytest.fixture(scope="session")
def api_service(
    database_url: str, broker_prefix: str, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Service]:
    """Local storage and a queue no worker consumes: for tests of the API alone."""
    tmp = tmp_path_factory.mktemp("api-service")
    service = Service(make_settings(database_url, broker_prefix, tmp, backend="local"))
    yield service
    service.client.close()


@pytest.fixture(scope="session")
def s3_api_service(
    database_url: str,
    broker_prefix: str,
    s3_endpoint: str,
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[Service]:
    """S3 storage and a queue no worker consumes: for tests of the API alone."""
    tmp = tmp_path_factory.mktemp("s3-api-service")
    settings = make_settings(
        database_url, broker_prefix, tmp, backend="s3", s3_endpoint=s3_endpoint
    )
    service = Service(settings)
    yield service
    service.client.close()


class LiveServer:
    """The API served by uvicorn on a free port, in a thread (for the browser tests)."""

    def __init__(self, service: Service) -> None:
        import uvicorn

        self.port = free_port()
        config = uvicorn.Config(service.app, host="127.0.0.1", port=self.port, log_level="warning")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.url = f"http://127.0.0.1:{self.port}"

    def __enter__(self) -> LiveServer:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            assert time.monotonic() < deadline, "uvicorn did not start"
            time.sleep(0.05)
        return self

    def __exit__(self, *_: object) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=30)
