"""The state machine of jobs, their stages and their input files: every status change.

Nothing else assigns a status. Each event below checks that the move is allowed from
the current state (the tables) and raises `IllegalTransition` otherwise, then sets the
status and the timestamps and fields that go with it. Callers hold the job's row lock
(`services.domain.repositories.jobs.lock`) when several processes could race.

Job:    created → uploading → queued → running → succeeded | failed | cancelled;
        a finished job can be queued again (an admin re-run).
Stage:  pending → queued → running → succeeded | failed | cancelled; a transient error
        puts a running stage back to queued, a refused broker a queued one to pending,
        the sweeper a stalled running or queued one to queued (a new message), a
        re-run any of them to pending.
Upload: pending → uploading → uploaded; a bad checksum or a replacement → pending.
"""

from __future__ import annotations

import uuid
from collections.abc import Mapping
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

from services.core.models import InputFile, Job, JobStatus, Stage, StageStatus, UploadState
from services.domain.errors import IllegalTransition

J, S, U = JobStatus, StageStatus, UploadState

JOB_MOVES: Mapping[str, frozenset[str]] = {
    J.CREATED: frozenset({J.UPLOADING, J.QUEUED, J.CANCELLED}),
    J.UPLOADING: frozenset({J.QUEUED, J.CANCELLED}),
    J.QUEUED: frozenset({J.RUNNING, J.SUCCEEDED, J.FAILED, J.CANCELLED}),
    J.RUNNING: frozenset({J.SUCCEEDED, J.FAILED, J.CANCELLED}),
    J.SUCCEEDED: frozenset({J.QUEUED}),
    J.FAILED: frozenset({J.QUEUED}),
    J.CANCELLED: frozenset({J.QUEUED}),
}
STAGE_MOVES: Mapping[str, frozenset[str]] = {
    S.PENDING: frozenset({S.QUEUED, S.CANCELLED}),
    S.QUEUED: frozenset({S.QUEUED, S.PENDING, S.RUNNING, S.FAILED, S.CANCELLED}),
    S.RUNNING: frozenset({S.RUNNING, S.QUEUED, S.SUCCEEDED, S.FAILED, S.CANCELLED, S.PENDING}),
    S.SUCCEEDED: frozenset({S.PENDING}),
    S.FAILED: frozenset({S.PENDING}),
    S.CANCELLED: frozenset({S.PENDING}),
}
UPLOAD_MOVES: Mapping[str, frozenset[str]] = {
    U.PENDING: frozenset({U.UPLOADING}),
    U.UPLOADING: frozenset({U.UPLOADING, U.UPLOADED, U.PENDING}),
    U.UPLOADED: frozenset({U.PENDING}),
}

ACTIVE_JOB = (J.QUEUED, J.RUNNING)
FINISHED_JOB = (J.SUCCEEDED, J.FAILED, J.CANCELLED)
#: Jobs whose files may be uploaded or replaced (a finished job before an admin re-run).
UPLOADABLE_JOB = (J.CREATED, J.UPLOADING, J.FAILED, J.CANCELLED)
WAITING_STAGE = (S.PENDING, S.QUEUED)


def now() -> datetime:
    return datetime.now(UTC)


def _check(kind: str, moves: Mapping[str, frozenset[str]], current: str, new: StrEnum) -> None:
    if new not in moves[current]:
        raise IllegalTransition(f"a {current} {kind} cannot become {new}")


def _job(job: Job, new: JobStatus) -> None:
    _check("job", JOB_MOVES, job.status, new)
    job.status = new


def _stage(stage: Stage, new: StageStatus) -> None:
    _check("stage", STAGE_MOVES, stage.status, new)
    stage.status = new


def _upload(file: InputFile, new: UploadState) -> None:
    _check("upload", UPLOAD_MOVES, file.upload_state, new)
    file.upload_state = new


# -- uploads -------------------------------------------------------------------------------


def start_upload(job: Job, file: InputFile) -> None:
    """Bytes of `file` are arriving; a new job is now uploading."""
    if job.status not in UPLOADABLE_JOB:
        raise IllegalTransition(f"job {job.id} is {job.status}: its files cannot change now")
    if file.upload_state == U.UPLOADED:
        raise IllegalTransition(
            f"camera {file.camera} chapter {file.chapter} is already uploaded; "
            "POST …/replace to upload a different file"
        )
    _upload(file, U.UPLOADING)
    if job.status == J.CREATED:
        _job(job, J.UPLOADING)


def finish_upload(file: InputFile) -> None:
    """Every byte of `file` arrived and checked out."""
    _upload(file, U.UPLOADED)
    file.upload_id, file.uploaded_at = None, now()


def restart_upload(file: InputFile) -> None:
    """`file` must be sent again from its first byte (bad checksum, or replaced)."""
    if file.upload_state != U.PENDING:
        _upload(file, U.PENDING)
    file.upload_id, file.uploaded_at = None, None
    file.part_checksums, file.checksum = {}, None


# -- jobs ----------------------------------------------------------------------------------


def submit_job(job: Job) -> None:
    """A new job whose files are all uploaded is queued."""
    if job.status not in (J.CREATED, J.UPLOADING):
        raise IllegalTransition(f"a {job.status} job cannot be submitted")
    _job(job, J.QUEUED)
    job.submitted_at = now()


def requeue_job(job: Job) -> None:
    """A finished job is queued again (re-run)."""
    if job.status not in FINISHED_JOB:
        raise IllegalTransition(f"a {job.status} job cannot become queued again")
    _job(job, J.QUEUED)
    job.error, job.finished_at = None, None


def start_job(job: Job) -> None:
    """The first stage of a queued job started."""
    if job.status == J.QUEUED:
        _job(job, J.RUNNING)
        job.started_at = job.started_at or now()


def finish_job(job: Job, status: JobStatus, error: str | None = None) -> None:
    """Finish a job as succeeded, failed or cancelled; its waiting stages will not run."""
    _job(job, status)
    job.error, job.finished_at = error, now()
    for stage in job.stages:
        if stage.status in WAITING_STAGE:
            _stage(stage, S.CANCELLED)
            stage.queue_token = None


# -- stages --------------------------------------------------------------------------------


def queue_stage(stage: Stage) -> str:
    """Mark a pending stage queued with a fresh delivery token; returns the token."""
    _stage(stage, S.QUEUED)
    stage.queued_at, stage.queue_token = now(), uuid.uuid4().hex
    stage.deliveries, stage.error, stage.heartbeat_at = 0, None, None
    return stage.queue_token


def unqueue_stage(stage: Stage) -> None:
    """The broker refused the stage's message: back to pending, to be queued again."""
    _stage(stage, S.PENDING)
    stage.queue_token = None


def start_stage(stage: Stage) -> None:
    """A worker took the stage's message (again, if a previous worker was lost)."""
    if stage.status == S.RUNNING:
        stage.warnings = [*stage.warnings, f"attempt {stage.attempt}: the worker was lost"]
    _stage(stage, S.RUNNING)
    stage.started_at, stage.finished_at = now(), None
    stage.heartbeat_at, stage.stalled_at = stage.started_at, None
    stage.attempt += 1
    stage.deliveries += 1
    stage.progress = 0.0


def requeue_stalled(stage: Stage, silent_s: float) -> str:
    """The worker running a stage, or holding its message, fell silent: queue a new
    attempt; returns its token.

    The delivery count is kept (unlike `queue_stage`), so a stage that kills every
    worker it lands on still fails after ``max_attempts``; the new token makes the
    lost delivery's message, should it ever come back, a harmless stale one.
    """
    _stage(stage, S.QUEUED)
    stage.stalled_at = stage.queued_at = now()
    stage.queue_token, stage.heartbeat_at = uuid.uuid4().hex, None
    stage.warnings = [
        *stage.warnings,
        f"attempt {stage.attempt}: stalled (no heartbeat for {silent_s:.0f} s), "
        f"re-queued at {stage.stalled_at:%Y-%m-%d %H:%M:%S} UTC",
    ]
    return stage.queue_token


def succeed_stage(stage: Stage, metrics: dict[str, Any], warnings: list[str]) -> None:
    _stage(stage, S.SUCCEEDED)
    stage.progress, stage.finished_at = 1.0, now()
    stage.metrics = metrics
    stage.warnings = [*stage.warnings, *warnings]
    stage.error = None


def fail_stage(stage: Stage, error: str) -> None:
    _stage(stage, S.FAILED)
    stage.error, stage.finished_at = error, now()


def stop_stage(stage: Stage, reason: str) -> None:
    """A running stage noticed that its job is no longer running, and stopped."""
    _stage(stage, S.CANCELLED)
    stage.error, stage.finished_at = reason, now()


def retry_stage(stage: Stage, note: str) -> None:
    """A transient error: the stage waits for its next delivery."""
    if stage.status != S.QUEUED:
        _stage(stage, S.QUEUED)
    stage.error, stage.heartbeat_at = note, None


def reset_stage(stage: Stage) -> None:
    """Forget a stage's run (an admin re-run from it or an earlier stage)."""
    if stage.status != S.PENDING:
        _stage(stage, S.PENDING)
    stage.progress, stage.queue_token = 0.0, None
    stage.deliveries, stage.error, stage.metrics, stage.warnings = 0, None, {}, []
    stage.queued_at = stage.started_at = stage.finished_at = None
    stage.heartbeat_at = stage.stalled_at = None
