"""Admin listing and re-run requests (their execution is covered by the worker tests)."""

from __future__ import annotations

import uuid

import pytest

from services.core.db import transaction
from services.core.models import Job
from services.domain.states import finish_job
from tests.services.conftest import Service
from tests.services.domain.test_sweeper import silent_for
from tests.services.helpers import TEST_ADMIN_TOKEN, auth, create_night, make_team, queued_stage

ADMIN = auth(TEST_ADMIN_TOKEN)
FILES = [
    {"camera": c, "chapter": 0, "filename": "GS010001.mp4", "size": 10, "sha256": "d" * 64}
    for c in (1, 2)
]


@pytest.fixture
def failed_job(api_service: Service) -> dict:
    """A job of a new team that failed (set directly: no worker consumes this queue)."""
    token = make_team(api_service.sessions)
    night = create_night(api_service.client, token)
    job = api_service.client.post(
        "/api/v1/jobs", json={"night_id": night["id"], "files": FILES}, headers=auth(token)
    ).json()
    with transaction(api_service.sessions) as session:
        row = session.get_one(Job, uuid.UUID(job["id"]))
        row.status = "running"  # as if it had been submitted
        finish_job(row, "failed", "probe failed: GS010001.mp4: not a video")
    return {**job, "token": token}


def test_list_failed_jobs(api_service: Service, failed_job: dict) -> None:
    response = api_service.client.get("/api/v1/admin/jobs?status=failed", headers=ADMIN)
    assert response.status_code == 200
    listed = {j["id"]: j for j in response.json()}
    assert listed[failed_job["id"]]["error"] == "probe failed: GS010001.mp4: not a video"
    assert all(j["status"] == "failed" for j in listed.values())
    created = api_service.client.get("/api/v1/admin/jobs?status=created", headers=ADMIN).json()
    assert failed_job["id"] not in {j["id"] for j in created}
    bad = api_service.client.get("/api/v1/admin/jobs?status=broken", headers=ADMIN)
    assert bad.status_code == 422


def test_rerun_requests_are_checked(api_service: Service, failed_job: dict) -> None:
    client = api_service.client
    url = f"/api/v1/admin/jobs/{failed_job['id']}/rerun"
    unknown = client.post(url, json={"from_stage": "calibrate"}, headers=ADMIN)
    assert unknown.status_code == 422 and "from_stage" in unknown.text
    params = client.post(url, json={"params": {"chunk_s": 0}}, headers=ADMIN)
    assert params.status_code == 422 and "chunk_s: Input should be greater than 0" in params.text
    not_uploaded = client.post(url, json={}, headers=ADMIN)
    assert not_uploaded.status_code == 409
    assert not_uploaded.json()["detail"].startswith("not uploaded yet: camera 1 chapter 0")
    missing = client.post(f"/api/v1/admin/jobs/{uuid.uuid4()}/rerun", json={}, headers=ADMIN)
    assert missing.status_code == 404


def test_rerun_of_an_unfinished_job_is_refused(api_service: Service) -> None:
    token = make_team(api_service.sessions)
    night = create_night(api_service.client, token)
    job = api_service.client.post(
        "/api/v1/jobs", json={"night_id": night["id"], "files": FILES}, headers=auth(token)
    ).json()
    response = api_service.client.post(
        f"/api/v1/admin/jobs/{job['id']}/rerun", json={}, headers=ADMIN
    )
    assert response.status_code == 409
    assert (
        response.json()["detail"] == f"job {job['id']} is created; only a finished job can re-run"
    )


def test_rerun_failed_of_a_night(api_service: Service, failed_job: dict) -> None:
    client = api_service.client
    url = f"/api/v1/admin/nights/{failed_job['night_id']}/rerun-failed"
    response = client.post(url, headers=ADMIN)
    assert response.status_code == 409  # its files were never uploaded
    assert (
        client.post(f"/api/v1/admin/nights/{uuid.uuid4()}/rerun-failed", headers=ADMIN).status_code
        == 404
    )


def test_list_stalled_jobs(api_service: Service) -> None:
    job_id, _, _ = queued_stage(api_service.sessions, status="running")
    silent_for(api_service.sessions, job_id, 2 * api_service.settings.stall_limit_s)
    response = api_service.client.get("/api/v1/admin/jobs?status=stalled", headers=ADMIN)
    assert response.status_code == 200, response.text
    listed = {j["id"]: j for j in response.json()}
    assert listed[job_id]["status"] == "running" and listed[job_id]["stalled_at"] is not None
    running = api_service.client.get("/api/v1/admin/jobs?status=running", headers=ADMIN).json()
    assert all(j["stalled_at"] is None for j in running if j["id"] != job_id)
