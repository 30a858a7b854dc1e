"""Faults: a worker killed mid-chunk, a corrupt chapter, a corrupted upload, a cancel."""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Iterator
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
from kombu import Connection
from sqlalchemy import select

from pipeline.artifacts import CALIBRATION_JSON, CAMERAS, TRAJECTORIES_CSV, flashes_name
from services.core.models import Artifact, Stage
from services.core.settings import Settings
from tests.services.conftest import RABBITMQ, REDIS, Service, WorkerProcess, make_settings
from tests.services.helpers import (
    TEST_ADMIN_TOKEN,
    TEST_PARAMS,
    auth,
    create_job,
    declare,
    download,
    make_team,
    submit,
    upload_all,
    upload_stream,
    wait_for_job,
)

pytestmark = pytest.mark.slow


def stage_rows(service: Service, job_id: str) -> list[Stage]:
    with service.sessions() as session:
        return list(session.scalars(select(Stage).where(Stage.job_id == uuid.UUID(job_id))))


def wait_for_stage(
    service: Service, job_id: str, ready: Callable[[Stage], bool], timeout: float = 120.0
) -> Stage:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = [s for s in stage_rows(service, job_id) if ready(s)]
        if found:
            return found[0]
        time.sleep(0.02)
    raise AssertionError(f"no stage of job {job_id} reached the state in {timeout} s")


# -- a whole worker machine dies in the middle of a tracking chunk ------------------------

#: One long chunk per camera (0–540) on the same 6 s background grid as the reference.
KILL_PARAMS = {**TEST_PARAMS, "chunk_s": 18}
#: Silence after which the sweeper re-queues a running stage in these tests.
STALL_LIMIT_S = 6.0
RESULTS = (TRAJECTORIES_CSV, CALIBRATION_JSON, *(flashes_name(c) for c in CAMERAS))


@pytest.fixture(params=["redis", "rabbitmq"])
def kill_service(
    request: pytest.FixtureRequest, database_url: str, broker_prefix: str, tmp_path: Path
) -> Iterator[tuple[Service, Settings]]:
    # Redis would hand the lost messages out again only after its visibility timeout
    # (180 s here, an hour by default): the recovery within the stall limit is the
    # sweeper's. RabbitMQ hands them out as soon as the dead worker's connection drops.
    settings = make_settings(
        database_url,
        broker_prefix,
        tmp_path,
        backend="local",
        broker_url=REDIS if request.param == "redis" else RABBITMQ,
        stall_limit_s=STALL_LIMIT_S,
        sweep_interval_s=1.0,
        heartbeat_interval_s=0.5,
    )
    service = Service(settings)
    yield service, settings
    service.client.close()
    if request.param == "rabbitmq":
        with Connection(RABBITMQ) as connection:
            connection.default_channel.queue_delete(settings.queue)


def test_killed_worker_machine_is_recovered_within_the_stall_limit(
    kill_service: tuple[Service, Settings], recording: dict, reference: Path, tmp_path: Path
) -> None:
    service, settings = kill_service
    first = WorkerProcess(settings, tmp_path / "worker-1.log", "first").start()
    second = WorkerProcess(settings, tmp_path / "worker-2.log", "second")
    try:
        token = make_team(service.sessions)
        job = create_job(service.client, token, recording, params=KILL_PARAMS)
        upload_all(service.client, token, job, recording)
        submit(service.client, token, job["id"])
        victim = wait_for_stage(
            service,
            job["id"],
            lambda s: s.name == "track" and s.status == "running" and 0 < s.progress < 0.6,
        )
        first.kill()  # main process and pool: the machine is gone
        killed_at = time.monotonic()
        killed = {s.key for s in stage_rows(service, job["id"]) if s.status == "running"}
        assert victim.key in killed  # it was still mid-chunk when its worker died
        second.start()
        done = wait_for_job(service.client, token, job["id"], timeout=STALL_LIMIT_S + 120)
        recovered_s = time.monotonic() - killed_at
    finally:
        first.stop()
        second.stop()

    assert done["status"] == "succeeded", done["error"]
    assert recovered_s < STALL_LIMIT_S + 60, recovered_s
    rows = stage_rows(service, job["id"])
    assert len({s.key for s in rows}) == len(rows) == 16  # 12 + 2 chunks per camera
    for stage in rows:
        assert stage.status == "succeeded"
        assert stage.attempt == (2 if stage.key in killed else 1), stage.key
    lost = next(s for s in rows if s.key == victim.key).warnings
    assert any("stalled" in w or "worker was lost" in w for w in lost), lost
    with service.sessions() as session:
        names = list(
            session.scalars(select(Artifact.name).where(Artifact.job_id == uuid.UUID(job["id"])))
        )
    assert len(names) == len(set(names))
    stored = service.storage.list_keys(f"jobs/{job['id']}/")
    inputs = [
        f"jobs/{job['id']}/input/cam{f['camera']}/{f['chapter']:02d}.mp4" for f in job["files"]
    ]
    assert sorted(stored) == sorted([f"jobs/{job['id']}/{n}" for n in names] + inputs)
    for name in RESULTS:  # byte-identical to an undisturbed run
        assert download(service.client, token, job["id"], name) == (reference / name).read_bytes()


# -- a corrupt chapter, replaced, then an admin re-run ----------------------------------------


def corrupted_copy(path: Path, out: Path) -> Path:
    """The file with its middle 40 % overwritten: it probes fine but cannot be decoded."""
    data = bytearray(path.read_bytes())
    a, b = int(len(data) * 0.3), int(len(data) * 0.7)
    data[a:b] = np.random.default_rng(0).integers(0, 256, b - a, dtype=np.uint8).tobytes()
    out.mkdir(parents=True, exist_ok=True)
    target = out / path.name
    target.write_bytes(bytes(data))
    return target


def test_corrupt_chapter_fails_then_rerun_from_track_succeeds(
    local_service: Service,
    local_worker: WorkerProcess,
    recording: dict,
    reference: Path,
    tmp_path: Path,
) -> None:
    client = local_service.client
    bad = {1: recording[1], 2: [recording[2][0], corrupted_copy(recording[2][1], tmp_path)]}
    token = make_team(local_service.sessions)
    job = create_job(client, token, bad)
    upload_all(client, token, job, bad)
    submit(client, token, job["id"])
    failed = wait_for_job(client, token, job["id"])

    assert failed["status"] == "failed"
    assert "track camera 2" in failed["error"] and recording[2][1].name in failed["error"]
    assert "corrupt" in failed["error"]
    probe = next(s for s in failed["stages"] if s["name"] == "probe")
    assert probe["status"] == "succeeded" and probe["attempt"] == 1
    broken = [s for s in failed["stages"] if s["status"] == "failed"]
    assert {(s["name"], s["camera"]) for s in broken} == {("track", 2)}  # chunks reading it
    assert any(s["error"] in failed["error"] for s in broken)
    assert all(s["status"] != "queued" for s in failed["stages"])

    good = recording[2][1]
    replaced = client.post(
        f"/api/v1/jobs/{job['id']}/files/2/1/replace",
        json=declare({2: [good]})[0] | {"chapter": 1},
        headers=auth(token),
    )
    assert replaced.status_code == 200, replaced.text
    assert replaced.json()["upload_state"] == "pending"
    upload_stream(client, token, replaced.json()["upload_url"], good, replaced.json()["part_size"])
    rerun = client.post(
        f"/api/v1/admin/jobs/{job['id']}/rerun", json={}, headers=auth(TEST_ADMIN_TOKEN)
    )
    assert rerun.status_code == 200, rerun.text
    assert rerun.json()["from_stage"] == "track"
    done = wait_for_job(client, token, job["id"])

    assert done["status"] == "succeeded", done["error"]
    assert done["error"] is None
    probe_after = next(s for s in done["stages"] if s["name"] == "probe")
    assert probe_after == probe  # not run again: same attempt, same timestamps
    tracks = [s for s in done["stages"] if s["name"] == "track"]
    failed_at = datetime.fromisoformat(failed["finished_at"])
    assert len(tracks) == 8
    assert all(datetime.fromisoformat(s["started_at"]) > failed_at for s in tracks)
    assert (
        download(client, token, job["id"], TRAJECTORIES_CSV)
        == (reference / TRAJECTORIES_CSV).read_bytes()
    )


def test_upload_corrupted_in_transit_fails_probe_with_checksums(
    s3_service: Service, s3_worker: WorkerProcess, recording: dict, tmp_path: Path
) -> None:
    client = s3_service.client
    token = make_team(s3_service.sessions)
    job = create_job(client, token, recording)
    damaged = dict(recording)
    damaged[1] = [corrupted_copy(recording[1][0], tmp_path)]  # bytes differ from the declaration
    upload_all(client, token, job, damaged)
    submit(client, token, job["id"])
    failed = wait_for_job(client, token, job["id"])

    assert failed["status"] == "failed"
    assert failed["error"].startswith("probe failed: camera 1 chapter 0")
    assert "SHA-256" in failed["error"] and job["files"][0]["sha256"] in failed["error"]
    assert [s["status"] for s in failed["stages"] if s["name"] != "probe"] == ["cancelled"] * 11


def test_cancel_stops_a_running_job(
    local_service: Service, local_worker: WorkerProcess, recording: dict
) -> None:
    client = local_service.client
    token = make_team(local_service.sessions)
    job = create_job(client, token, recording, params=KILL_PARAMS)
    upload_all(client, token, job, recording)
    submit(client, token, job["id"])
    wait_for_stage(local_service, job["id"], lambda s: s.name == "track" and s.status == "running")
    cancelled = client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=auth(token))
    assert cancelled.status_code == 200, cancelled.text
    assert cancelled.json()["status"] == "cancelled"

    deadline = time.monotonic() + 60
    while any(s.status in ("running", "queued") for s in stage_rows(local_service, job["id"])):
        assert time.monotonic() < deadline, "stages still running after the cancel"
        time.sleep(0.2)
    rows = stage_rows(local_service, job["id"])
    tracks = [s.status for s in rows if s.name == "track"]
    assert "cancelled" in tracks and set(tracks) <= {"cancelled", "succeeded"}
    # The clock waits for the probe alone and takes milliseconds: it may have finished.
    assert {s.status for s in rows if s.name == "clock"} <= {"cancelled", "succeeded"}
    after_tracking = {s.status for s in rows if s.name not in ("probe", "track", "clock")}
    assert after_tracking == {"cancelled"}
    again = client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=auth(token))
    assert again.status_code == 409
