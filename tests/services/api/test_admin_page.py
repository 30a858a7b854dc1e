"""The admin page in headless Chromium: a failed job's file replaced, then a re-run from a
chosen stage with a parameter override."""

from __future__ import annotations

import os
import uuid
from pathlib import Path

from playwright.sync_api import Browser

from pipeline.graph import plan
from pipeline.params import ProcessParams
from pipeline.probe import StereoProbe
from services.core.db import transaction
from services.core.models import Job
from services.domain.states import finish_job
from services.domain.workflow import new_stage
from tests.services.api.test_pages import browser  # noqa: F401  (the fixture)
from tests.services.conftest import LiveServer, Service
from tests.services.helpers import (
    TEST_ADMIN_TOKEN,
    auth,
    create_night,
    make_team,
    record_outputs,
)

FILES = [
    {"camera": c, "chapter": 0, "filename": f"cam{c}.mp4", "size": 10, "sha256": "e" * 64}
    for c in (1, 2)
]


def failed_job(service: Service) -> str:
    """An uploaded job whose sync stage failed (no worker consumes this service's queue)."""
    token = make_team(service.sessions)
    night = create_night(service.client, token)
    job = service.client.post(
        "/api/v1/jobs", json={"night_id": night["id"], "files": FILES}, headers=auth(token)
    ).json()
    with transaction(service.sessions) as session:
        row = session.get_one(Job, uuid.UUID(job["id"]))
        for file in row.files:
            file.upload_state = "uploaded"
        probe = StereoProbe(width=640, height=320, fps=30.0, n_frames={1: 600, 2: 600})
        row.stages = [new_stage(u) for u in plan(probe, ProcessParams())]  # one chunk each
        for stage in row.stages:
            stage.status = "succeeded" if stage.name in ("probe", "track", "merge") else "pending"
        session.flush()
        for stage in row.stages:
            if stage.status == "succeeded":
                record_outputs(session, row.id, stage)
        row.status = "running"
        next(s for s in row.stages if s.name == "sync").status = "failed"
        finish_job(row, "failed", "sync failed: no flash seen by both cameras")
    return str(job["id"])


def test_admin_page_replaces_a_file_and_reruns_with_an_override(
    api_service: Service,
    browser: Browser,  # noqa: F811
    tmp_path: Path,
) -> None:
    job_id = failed_job(api_service)
    replacement = tmp_path / "cam2-fixed.mp4"
    replacement.write_bytes(os.urandom(7 << 20))  # two parts on the stream path
    page = browser.new_page()
    with LiveServer(api_service) as server:
        page.goto(f"{server.url}/admin")
        page.fill("#admin-token", TEST_ADMIN_TOKEN)
        page.click("#load")
        row = page.locator(f'tr[data-job="{job_id}"]')
        row.wait_for()
        assert "sync failed: no flash seen by both cameras" in row.inner_text()
        assert row.locator("td").nth(4).inner_text().endswith("min")  # its age
        row.locator("summary").click()

        row.locator(".replace-camera").select_option("2")
        row.locator(".replace-file").set_input_files(str(replacement))
        row.locator(".replace").click()
        page.wait_for_selector("#admin-status:has-text('replaced by cam2-fixed.mp4')")

        row.locator(".rerun-stage").select_option("pose")  # sync failed: too late, refused
        row.locator(".rerun").click()
        page.wait_for_selector("#admin-status:has-text('stage sync of job')")
        row.locator(".rerun-stage").select_option("sync")
        row.locator(".param-name").select_option("sync.window_s")
        assert "RANSAC window" in row.locator(".param-help").inner_text()  # its description
        row.locator(".param-value").fill("5")
        row.locator(".add-override").click()
        row.locator(".rerun").click()
        page.wait_for_selector(f"#admin-status:has-text('job {job_id} re-queued from sync')")
        assert page.locator(f'tr[data-job="{job_id}"]').count() == 0  # no longer failed
    page.close()
    job = api_service.client.get(f"/api/v1/jobs/{job_id}", headers=auth(TEST_ADMIN_TOKEN)).json()
    assert job["status"] == "queued" and job["error"] is None
    assert job["params"]["sync"]["window_s"] == 5
    replaced = next(f for f in job["files"] if f["camera"] == 2)
    assert (replaced["filename"], replaced["upload_state"]) == ("cam2-fixed.mp4", "uploaded")
    key = f"jobs/{job_id}/input/cam2/00.mp4"
    assert b"".join(api_service.storage.iter_bytes(key)) == replacement.read_bytes()
    statuses = {s["name"]: s["status"] for s in job["stages"]}
    assert (statuses["merge"], statuses["sync"], statuses["pose"]) == (
        "succeeded",
        "queued",
        "pending",
    )
