"""``firefly3d admin create-team``: the token is printed once and only its hash is stored."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import httpx
from sqlalchemy import select

from services.core.db import SessionFactory
from services.core.models import Team
from services.core.security import hash_token
from tests.services.conftest import Service, free_port
from tests.services.helpers import auth, create_night

FIREFLY3D = str(Path(sys.executable).with_name("firefly3d"))


def run_cli(database_url: str, *args: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIREFLY3D_")}
    env["FIREFLY3D_DATABASE_URL"] = database_url
    return subprocess.run([FIREFLY3D, *args], env=env, capture_output=True, text=True, check=False)


def test_create_team_prints_a_working_token_once(
    database_url: str, sessions: SessionFactory, api_service: Service
) -> None:
    name = f"Fireflies of {uuid.uuid4().hex[:6]}"
    result = run_cli(database_url, "admin", "create-team", name)
    assert result.returncode == 0, result.stderr
    token = result.stdout.strip()
    assert token.startswith("ff3d_") and "cannot be shown again" in result.stderr
    with sessions() as session:
        team = session.scalars(select(Team).where(Team.name == name)).one()
        assert [t.token_hash for t in team.tokens] == [hash_token(token)]
        assert token not in {team.name, team.tokens[0].token_hash}
    night = create_night(api_service.client, token)
    assert (
        api_service.client.get(f"/api/v1/nights/{night['id']}", headers=auth(token)).status_code
        == 200
    )

    duplicate = run_cli(database_url, "admin", "create-team", name)
    assert duplicate.returncode == 1
    assert duplicate.stdout == "" and f"team {name!r} already exists" in duplicate.stderr


def test_tokens_are_listed_revoked_and_rotated(database_url: str, api_service: Service) -> None:
    name = f"Rotators {uuid.uuid4().hex[:6]}"
    first = run_cli(database_url, "admin", "create-team", name).stdout.strip()
    laptop = run_cli(
        database_url, "admin", "issue-token", name, "--label", "laptop", "--expires-in-days", "30"
    )
    assert laptop.returncode == 0, laptop.stderr
    listing = run_cli(database_url, "admin", "list-tokens").stdout
    mine = [line for line in listing.splitlines() if name in line]
    assert len(mine) == 2 and any("laptop" in line and "valid until" in line for line in mine)
    assert first not in listing and laptop.stdout.strip() not in listing

    initial_id = next(line.split()[0] for line in mine if "initial" in line)
    assert run_cli(database_url, "admin", "revoke-token", initial_id).returncode == 0
    assert "revoked" in run_cli(database_url, "admin", "list-tokens").stdout
    rotated = run_cli(database_url, "admin", "rotate-token", name)
    assert rotated.returncode == 0, rotated.stderr
    client = api_service.client
    for old in (first, laptop.stdout.strip()):
        assert client.get("/api/v1/nights", headers=auth(old)).status_code == 401
    assert client.get("/api/v1/nights", headers=auth(rotated.stdout.strip())).status_code == 200
    unknown = run_cli(database_url, "admin", "revoke-token", "not-an-id")
    assert unknown.returncode == 1 and "is not a token ID" in unknown.stderr


def test_service_commands_are_registered() -> None:
    result = subprocess.run([FIREFLY3D, "--help"], capture_output=True, text=True, check=True)
    for command in ("admin", "serve", "worker"):
        assert f"    {command} " in result.stdout
    worker = subprocess.run(
        [FIREFLY3D, "worker", "--help"], capture_output=True, text=True, check=True
    )
    assert "--concurrency" in worker.stdout and "--queues" in worker.stdout


def test_serve_needs_the_shared_secret(database_url: str) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIREFLY3D_")}
    env["FIREFLY3D_DATABASE_URL"] = database_url
    result = subprocess.run(
        [FIREFLY3D, "serve", "--port", str(free_port()), "--workers", "1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode != 0
    assert "FIREFLY3D_SECRET_KEY is not set" in result.stderr


def test_serve_starts_the_api(database_url: str) -> None:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIREFLY3D_")}
    env["FIREFLY3D_DATABASE_URL"] = database_url
    env["FIREFLY3D_SECRET_KEY"] = "shared-by-every-api-process"
    server = subprocess.Popen(
        [FIREFLY3D, "serve", "--port", str(port)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                response = httpx.get(f"http://127.0.0.1:{port}/healthz")
                break
            except httpx.TransportError:
                assert time.monotonic() < deadline and server.poll() is None, "serve did not start"
                time.sleep(0.2)
        assert response.json() == {"status": "ok"}
        assert httpx.get(f"http://127.0.0.1:{port}/").text.count('type="file"') == 2
    finally:
        server.terminate()
        server.wait(timeout=30)
