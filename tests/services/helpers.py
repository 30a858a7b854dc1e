"""Client-side steps of the service tests: teams, nights, jobs, uploads, polling."""

from __future__ import annotations

import datetime as dt
import hashlib
import time
import uuid
from pathlib import Path
from typing import Any

import httpx
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from pipeline.graph import Unit, writes
from services.core.db import SessionFactory, transaction
from services.core.models import Job, Night, Stage, Team
from services.domain import teams
from services.domain.repositories import jobs
from services.domain.workflow import job_key, new_stage, unit_of

TEST_ADMIN_TOKEN = "test-admin-token"
#: Parameters of every test job: 6 s tracking chunks, so each camera has 4 in 20 s.
TEST_PARAMS: dict[str, Any] = {"chunk_s": 6, "tracking": {"block_s": 6}}
NIGHT = {
    "site": "Test meadow",
    "date": "2026-06-12",
    "latitude": 35.6,
    "longitude": -83.5,
    "separation_m": 1.5,
    "height_m": 1.2,
    "notes": "simulated",
    # Real time: camera 1 started at 21:30 local time, 40 min after sunset there.
    "time_zone": "America/New_York",
    "start_time": "2026-06-12T21:30:00",
    "camera_model": "GoPro Max",
}
FINISHED = ("succeeded", "failed", "cancelled")


def auth(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def make_team(sessions: SessionFactory, name: str | None = None) -> str:
    """A team in the database; returns its token."""
    with sessions() as session:
        return teams.create_team(session, name or f"team-{uuid.uuid4().hex[:8]}").secret


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def declare(cameras: dict[int, list[Path]]) -> list[dict[str, Any]]:
    """File declarations of each camera's chapters, in order."""
    return [
        {
            "camera": camera,
            "chapter": chapter,
            "filename": path.name,
            "size": path.stat().st_size,
            "sha256": sha256(path),
        }
        for camera, paths in cameras.items()
        for chapter, path in enumerate(paths)
    ]


def create_night(client: TestClient, token: str, **changes: Any) -> dict[str, Any]:
    response = client.post("/api/v1/nights", json={**NIGHT, **changes}, headers=auth(token))
    assert response.status_code == 201, response.text
    return response.json()


def create_job(
    client: TestClient,
    token: str,
    cameras: dict[int, list[Path]],
    params: dict[str, Any] | None = None,
) -> dict[str, Any]:
    night = create_night(client, token)
    body = {"night_id": night["id"], "files": declare(cameras), "params": params or TEST_PARAMS}
    response = client.post("/api/v1/jobs", json=body, headers=auth(token))
    assert response.status_code == 201, response.text
    return response.json()


def upload_stream(
    client: TestClient, token: str, url: str, path: Path, piece: int, offset: int = 0
) -> dict[str, Any]:
    """PUT a file from `offset` on in `piece`-byte ranges, as the upload page does."""
    data, size = path.read_bytes(), path.stat().st_size
    status: dict[str, Any] = {}
    for start in range(offset, size, piece):
        end = min(start + piece, size)
        headers = {**auth(token), "Content-Range": f"bytes {start}-{end - 1}/{size}"}
        response = client.put(url, content=data[start:end], headers=headers)
        assert response.status_code == 200, response.text
        status = response.json()
    return status


def upload_multipart(client: TestClient, token: str, url: str, path: Path) -> dict[str, Any]:
    """Sign every part, PUT them to S3 directly (as a browser would), complete."""
    info = client.get(url, headers=auth(token)).json()
    numbers = list(range(1, info["part_count"] + 1))
    signed = client.post(f"{url}/parts", json={"part_numbers": numbers}, headers=auth(token))
    assert signed.status_code == 200, signed.text
    data = path.read_bytes()
    for part in signed.json()["parts"]:
        start = (part["number"] - 1) * info["part_size"]
        response = httpx.put(part["url"], content=data[start : start + info["part_size"]])
        assert response.status_code == 200, response.text
    done = client.post(f"{url}/complete", headers=auth(token))
    assert done.status_code == 200, done.text
    return done.json()


def upload_all(
    client: TestClient, token: str, job: dict[str, Any], cameras: dict[int, list[Path]]
) -> None:
    for file in job["files"]:
        path = cameras[file["camera"]][file["chapter"]]
        if file["method"] == "stream":
            status = upload_stream(client, token, file["upload_url"], path, file["part_size"])
        else:
            status = upload_multipart(client, token, file["upload_url"], path)
        assert status["upload_state"] == "uploaded"


def submit(client: TestClient, token: str, job_id: str) -> dict[str, Any]:
    response = client.post(f"/api/v1/jobs/{job_id}/submit", headers=auth(token))
    assert response.status_code == 200, response.text
    return response.json()


def wait_for_job(
    client: TestClient,
    token: str,
    job_id: str,
    timeout: float = 240.0,
    until: tuple[str, ...] = FINISHED,
) -> dict[str, Any]:
    """Poll the job until its status is in `until`."""
    deadline = time.monotonic() + timeout
    while True:
        job = client.get(f"/api/v1/jobs/{job_id}", headers=auth(token)).json()
        if job["status"] in until:
            return job
        assert time.monotonic() < deadline, f"job still {job['status']} after {timeout} s: {job}"
        time.sleep(0.5)


def download(client: TestClient, token: str, job_id: str, name: str) -> bytes:
    """An artifact through the API (following a presigned redirect to S3)."""
    response = client.get(
        f"/api/v1/jobs/{job_id}/artifacts/{name}", headers=auth(token), follow_redirects=False
    )
    if response.status_code == 307:
        response = httpx.get(response.headers["location"])
    assert response.status_code == 200, response.text
    return response.content


def queued_stage(
    sessions: SessionFactory, deliveries: int = 0, status: str = "queued", name: str = "sync"
) -> tuple[str, str, str]:
    """A running job whose one stage (``sync``) is queued with a token; returns (job, key,
    token)."""
    token = uuid.uuid4().hex
    with transaction(sessions) as session:
        team = Team(name=f"r-{uuid.uuid4().hex[:8]}")
        night = Night(team=team, site="s", date=dt.date(2026, 6, 1), separation_m=1.5, notes="")
        job = Job(
            id=uuid.uuid4(),
            night=night,
            status="running",
            params={"classifier": {"enabled": False}},
        )
        stage = new_stage(Unit(name))
        stage.status, stage.queue_token, stage.deliveries = status, token, deliveries
        job.stages = [stage]
        session.add(job)
    return str(job.id), name, token


def stage_row(sessions: SessionFactory, job_id: str) -> Stage:
    with sessions() as session:
        return session.get_one(Job, uuid.UUID(job_id)).stages[0]


def artifact_row(job_id: uuid.UUID, stage_id: int, name: str, size: int = 1) -> dict[str, Any]:
    """An artifact row (`jobs.save_artifact`) of a job's file `name`."""
    return {
        "job_id": job_id,
        "stage_id": stage_id,
        "name": name,
        "storage_key": job_key(job_id, name),
        "size": size,
        "content_type": "text/plain",
    }


def record_outputs(session: Session, job_id: uuid.UUID, stage: Stage) -> None:
    """Artifact rows for what a succeeded stage row's unit writes, as a worker records
    them (the stage must have its id: flush first)."""
    for name in writes(unit_of(stage)):
        jobs.save_artifact(session, artifact_row(job_id, stage.id, name))
