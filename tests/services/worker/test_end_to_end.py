"""A simulated stereo recording through the whole service, compared with the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipeline.artifacts import (
    CALIBRATION_JSON,
    FLASH_PATTERNS_CSV,
    SUMMARY_JSON,
    TRAJECTORIES_CSV,
    flashes_name,
)
from tests.services.conftest import Service, WorkerProcess
from tests.services.helpers import (
    auth,
    create_job,
    download,
    make_team,
    submit,
    upload_all,
    wait_for_job,
)

pytestmark = pytest.mark.slow
TIMES = ("seconds", "fps")
COMPARED = (
    TRAJECTORIES_CSV,
    FLASH_PATTERNS_CSV,
    CALIBRATION_JSON,
    flashes_name(1),
    flashes_name(2),
)


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
    assert job["summary"]["counts"]["trajectories"] > 0
    check_same_graph_and_summary(service, token, job, reference)


def check_same_graph_and_summary(service: Service, token: str, job: dict, reference: Path) -> None:
    """The worker ran the units the CLI ran (one metrics file each), with one summary."""
    response = service.client.get(f"/api/v1/jobs/{job['id']}/artifacts", headers=auth(token))
    recorded = {a["name"] for a in response.json() if a["name"].endswith(".json")}
    by_service = {n for n in recorded if n.startswith(("work/metrics/", "work/tracking/"))}
    by_cli = {
        p.relative_to(reference).as_posix()
        for p in [*reference.glob("work/metrics/*.json"), *reference.glob("work/tracking/*/*.json")]
    }
    assert by_service == by_cli and len(by_cli) == 20  # probe, 8 chunks, 2 merges, 9 more
    cli_summary = json.loads((reference / SUMMARY_JSON).read_text())
    for key in (
        "counts",
        "delay_frames",
        "delay_confidence",
        "rotation",
        "translation",
        "clock",
        "patterns",
    ):
        assert job["summary"][key] == cli_summary[key], key
    for camera in ("cam1", "cam2"):
        stats = {k: v for k, v in job["summary"]["tracking"][camera].items() if k not in TIMES}
        assert stats == {k: v for k, v in cli_summary["tracking"][camera].items() if k not in TIMES}


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
