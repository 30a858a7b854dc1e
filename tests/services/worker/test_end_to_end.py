"""A simulated stereo recording through the whole service, compared with the CLI."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.artifacts import CALIBRATION_JSON, TRAJECTORIES_CSV, flashes_name
from tests.services.conftest import Service, WorkerProcess
from tests.services.helpers import (
    create_job,
    download,
    make_team,
    submit,
    upload_all,
    wait_for_job,
)

pytestmark = pytest.mark.slow
COMPARED = (TRAJECTORIES_CSV, CALIBRATION_JSON, flashes_name(1), flashes_name(2))


def run_job(service: Service, recording: dict[int, list[Path]]) -> tuple[str, dict]:
    token = make_team(service.sessions)
    job = create_job(service.client, token, recording)
    upload_all(service.client, token, job, recording)
    # The response shows the job as it is now: a fast worker may have started it already.
    assert submit(service.client, token, job["id"])["status"] in ("queued", "running")
    return token, wait_for_job(service.client, token, job["id"])


def check_outputs(service: Service, token: str, job: dict, reference: Path) -> None:
    assert job["status"] == "succeeded", job["error"]
    for name in COMPARED:
        assert download(service.client, token, job["id"], name) == (reference / name).read_bytes()
    tracks = [s for s in job["stages"] if s["name"] == "track"]
    assert len(tracks) == 8  # 4 chunks of 6 s per camera
    assert all(s["status"] == "succeeded" and s["attempt"] == 1 for s in job["stages"])
    assert job["progress"] == pytest.approx(1.0)
    assert job["summary"]["n_trajectories"] > 0


def test_stream_upload_to_local_storage(
    local_service: Service, local_worker: WorkerProcess, recording: dict, reference: Path
) -> None:
    token, job = run_job(local_service, recording)
    assert {f["method"] for f in job["files"]} == {"stream"}
    check_outputs(local_service, token, job, reference)


def test_multipart_upload_to_s3(
    s3_service: Service, s3_worker: WorkerProcess, recording: dict, reference: Path
) -> None:
    token, job = run_job(s3_service, recording)
    assert {f["method"] for f in job["files"]} == {"s3-multipart"}
    check_outputs(s3_service, token, job, reference)
