"""The state machine refuses every move its tables do not allow."""

from __future__ import annotations

import pytest

from pipeline.graph import Unit
from services.core.models import InputFile, Job, JobStatus, StageStatus, UploadState
from services.domain import states
from services.domain.errors import IllegalTransition
from services.domain.workflow import new_stage


def job(status: str) -> Job:
    row = Job(status=status, params={}, summary={})
    row.stages = [new_stage(Unit("probe")), new_stage(Unit("sync"))]
    return row


def test_tables_cover_every_state() -> None:
    assert set(states.JOB_MOVES) == set(JobStatus)
    assert set(states.STAGE_MOVES) == set(StageStatus)
    assert set(states.UPLOAD_MOVES) == set(UploadState)


@pytest.mark.parametrize("status", ["created", "uploading", "running"])
def test_only_a_finished_job_is_requeued(status: str) -> None:
    with pytest.raises(IllegalTransition, match=f"a {status} job cannot become queued"):
        states.requeue_job(job(status))


def test_finishing_cancels_waiting_stages_and_a_finished_job_stays_finished() -> None:
    row = job("running")
    states.queue_stage(row.stages[0])
    states.finish_job(row, JobStatus.CANCELLED, "cancelled by the team")
    assert [s.status for s in row.stages] == ["cancelled", "cancelled"]
    assert all(s.queue_token is None for s in row.stages)
    with pytest.raises(IllegalTransition, match="a cancelled job cannot become failed"):
        states.finish_job(row, JobStatus.FAILED, "late failure")


def test_a_stage_runs_only_once_queued_and_succeeds_only_while_running() -> None:
    stage = new_stage(Unit("sync"))
    with pytest.raises(IllegalTransition, match="a pending stage cannot become running"):
        states.start_stage(stage)
    token = states.queue_stage(stage)
    assert stage.queue_token == token and len(token) == 32
    states.start_stage(stage)
    states.start_stage(stage)  # redelivered after its worker was lost
    assert (stage.attempt, stage.warnings) == (2, ["attempt 1: the worker was lost"])
    states.succeed_stage(stage, {"delay_frames": 3}, [])
    with pytest.raises(IllegalTransition, match="a succeeded stage cannot become queued"):
        states.retry_stage(stage, "late retry")
    states.reset_stage(stage)
    assert (stage.status, stage.metrics, stage.attempt) == ("pending", {}, 2)


def test_uploads_go_pending_uploading_uploaded() -> None:
    row = job("created")
    file = InputFile(upload_state="pending")
    states.start_upload(row, file)
    assert (row.status, file.upload_state) == ("uploading", "uploading")
    states.finish_upload(file)
    with pytest.raises(IllegalTransition, match="already uploaded"):
        states.start_upload(row, file)
    states.restart_upload(file)
    assert file.upload_state == "pending" and file.uploaded_at is None
    with pytest.raises(IllegalTransition, match="a pending upload cannot become uploaded"):
        states.finish_upload(file)
    with pytest.raises(IllegalTransition, match="its files cannot change now"):
        states.start_upload(job("running"), file)
