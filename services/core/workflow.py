"""The job and stage state machine, kept in PostgreSQL.

A job's stages form a small graph: ``probe`` → ``track`` chunks (per camera, planned
from ``probe.json``) → ``merge`` (per camera, after all its chunks) → ``sync`` → ``pose``
→ ``triangulate`` → ``link`` → ``report``. `advance` is the only place that queues
stages: under a lock on the job row it marks every stage whose prerequisites succeeded
as queued with a fresh token, commits, and only then hands the messages to the broker
(enqueue after commit). Tasks carry that token, so a stale or duplicated message finds
a different token, or a finished stage, and does nothing.

Job: created → uploading → queued → running → succeeded | failed | cancelled; an
admin re-run puts a finished job back to queued. Stage: pending → queued → running →
succeeded | failed | cancelled (a transient error puts it back to queued).
"""

from __future__ import annotations

import tempfile
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from pipeline.artifacts import CAMERAS, PROBE_JSON
from services.core.db import SessionFactory, transaction
from services.core.models import Job, JobStatus, Stage, StageStatus
from services.core.storage import Storage

STAGES = ("probe", "track", "merge", "sync", "pose", "triangulate", "link", "report")
ACTIVE_JOB = (JobStatus.QUEUED, JobStatus.RUNNING)
FINISHED_JOB = (JobStatus.SUCCEEDED, JobStatus.FAILED, JobStatus.CANCELLED)
WAITING_STAGE = (StageStatus.PENDING, StageStatus.QUEUED)


class WorkflowError(Exception):
    """A request that the job's current state does not allow (HTTP 409)."""


class EnqueueError(Exception):
    """The broker did not take the messages; the stages went back to pending."""


@dataclass(frozen=True)
class StageMessage:
    """What a worker needs to find its stage row: sent as the task's arguments."""

    job_id: str
    key: str
    name: str
    token: str


Send = Callable[[list[StageMessage]], None]


def now() -> datetime:
    return datetime.now(UTC)


def job_key(job_id: uuid.UUID | str, name: str) -> str:
    """Storage key of a job's artifact or input (``name`` relative to the job folder)."""
    return f"jobs/{job_id}/{name}"


def stage_key(name: str, camera: int | None = None, start: int = 0, stop: int = 0) -> str:
    """Unique key of a stage row within its job (``track/cam1/00000000-00001800``)."""
    if name == "track":
        return f"track/cam{camera}/{start:08d}-{stop:08d}"
    return name if camera is None else f"{name}/cam{camera}"


def new_stage(name: str, camera: int | None = None, start: int = 0, stop: int = 0) -> Stage:
    """A pending stage row (every column set: `ready_stages` reads them before a flush)."""
    chunk = {"frame_start": start, "frame_stop": stop} if name == "track" else {}
    return Stage(
        key=stage_key(name, camera, start, stop),
        name=name,
        camera=camera,
        status=StageStatus.PENDING,
        attempt=0,
        deliveries=0,
        progress=0.0,
        metrics={},
        warnings=[],
        **chunk,
    )


def static_stages() -> list[Stage]:
    """Stage rows created at submission; tracking chunks are added once probed."""
    specs = [("probe", None), *(("merge", c) for c in CAMERAS)]
    specs += [(name, None) for name in STAGES[STAGES.index("sync") :]]
    return [new_stage(name, camera) for name, camera in specs]


def track_stages(plan: Iterable[tuple[int, int, int]]) -> list[Stage]:
    """Stage rows of planned ``(camera, start, stop)`` tracking chunks."""
    return [new_stage("track", camera, start, stop) for camera, start, stop in plan]


def _prerequisites(stage: Stage, stages: list[Stage]) -> list[Stage] | None:
    """Rows that must succeed before `stage` runs; None while they are not planned yet."""
    if stage.name == "probe":
        return []
    if stage.name == "track":
        return [s for s in stages if s.name == "probe"]
    if stage.name == "merge":
        chunks = [s for s in stages if s.name == "track" and s.camera == stage.camera]
        return chunks or None
    if stage.name == "sync":
        return [s for s in stages if s.name == "merge"]
    previous = STAGES[STAGES.index(stage.name) - 1]
    return [s for s in stages if s.name == previous]


def ready_stages(stages: list[Stage]) -> list[Stage]:
    """Pending stages whose prerequisites have all succeeded."""

    def ready(stage: Stage) -> bool:
        needed = _prerequisites(stage, stages)
        return needed is not None and all(s.status == StageStatus.SUCCEEDED for s in needed)

    return [s for s in stages if s.status == StageStatus.PENDING and ready(s)]


def _needs_plan(stages: list[Stage]) -> bool:
    probed = any(s.name == "probe" and s.status == StageStatus.SUCCEEDED for s in stages)
    return probed and not any(s.name == "track" for s in stages)


def _plan(job: Job, storage: Storage) -> list[tuple[int, int, int]]:
    from pipeline.run import ProcessParams, plan_chunks

    with tempfile.TemporaryDirectory(prefix="firefly3d-plan-") as tmp:
        workdir = Path(tmp)
        (workdir / PROBE_JSON).parent.mkdir(parents=True)
        storage.download_file(job_key(job.id, PROBE_JSON), workdir / PROBE_JSON)
        return plan_chunks(workdir, ProcessParams.model_validate(job.params))


def lock_job(session: Session, job_id: uuid.UUID | str) -> Job | None:
    """The job row, locked until the transaction ends (serialises state changes)."""
    return session.get(Job, uuid.UUID(str(job_id)), with_for_update=True)


def advance(
    sessions: SessionFactory, storage: Storage, send: Send, job_id: uuid.UUID | str
) -> None:
    """Queue whatever can run now; mark the job succeeded when every stage has.

    Raises
    ------
    EnqueueError
        If the broker refused the messages (the stages are pending again, so a later
        `advance` or an admin re-run queues them).
    """
    with transaction(sessions) as session:
        job = lock_job(session, job_id)
        if job is None or job.status not in ACTIVE_JOB:
            return
        if _needs_plan(job.stages):
            job.stages.extend(track_stages(_plan(job, storage)))
        stages = job.stages
        if all(s.status == StageStatus.SUCCEEDED for s in stages):
            job.status, job.finished_at = JobStatus.SUCCEEDED, now()
            return
        messages = [_queue(job, stage) for stage in ready_stages(stages)]
    _send_or_revert(sessions, send, messages)


def _queue(job: Job, stage: Stage) -> StageMessage:
    stage.status, stage.queued_at = StageStatus.QUEUED, now()
    stage.queue_token, stage.deliveries, stage.error = uuid.uuid4().hex, 0, None
    return StageMessage(str(job.id), stage.key, stage.name, stage.queue_token)


def _send_or_revert(sessions: SessionFactory, send: Send, messages: list[StageMessage]) -> None:
    if not messages:
        return
    try:
        send(messages)
    except Exception as exc:
        tokens = [m.token for m in messages]
        with transaction(sessions) as session:
            for stage in session.scalars(select(Stage).where(Stage.queue_token.in_(tokens))):
                if stage.status == StageStatus.QUEUED:
                    stage.status, stage.queue_token = StageStatus.PENDING, None
        raise EnqueueError(f"the task broker did not accept the job's stages: {exc}") from exc


def stop_job(job: Job, status: JobStatus, error: str | None = None) -> None:
    """Finish a job as failed or cancelled; its waiting stages will not run."""
    job.status, job.error, job.finished_at = status, error, now()
    for stage in job.stages:
        if stage.status in WAITING_STAGE:
            stage.status, stage.queue_token = StageStatus.CANCELLED, None


def submit(sessions: SessionFactory, storage: Storage, send: Send, job_id: uuid.UUID) -> None:
    """Queue a job whose inputs are all uploaded."""
    with transaction(sessions) as session:
        job = lock_job(session, job_id)
        if job is None:
            raise WorkflowError(f"job {job_id} does not exist")
        if job.status not in (JobStatus.CREATED, JobStatus.UPLOADING):
            raise WorkflowError(f"job {job.id} is {job.status}; only a new job can be submitted")
        _require_uploaded(job)
        if not job.stages:
            job.stages = static_stages()
        job.status, job.submitted_at = JobStatus.QUEUED, now()
    advance(sessions, storage, send, job_id)


def _require_uploaded(job: Job) -> None:
    missing = [
        f"camera {f.camera} chapter {f.chapter} ({f.filename})"
        for f in job.files
        if f.upload_state != "uploaded"
    ]
    if missing:
        raise WorkflowError(f"not uploaded yet: {', '.join(missing)}")


def cancel(sessions: SessionFactory, job_id: uuid.UUID) -> None:
    """Cancel a job that has not finished; running stages stop at their next progress report."""
    with transaction(sessions) as session:
        job = lock_job(session, job_id)
        if job is None:
            raise WorkflowError(f"job {job_id} does not exist")
        if job.status in FINISHED_JOB:
            raise WorkflowError(f"job {job.id} already finished ({job.status})")
        stop_job(job, JobStatus.CANCELLED, "cancelled by the team")


def default_rerun_stage(stages: list[Stage]) -> str | None:
    """The first stage, in pipeline order, that has not succeeded (None if all have)."""
    done = {
        name
        for name in STAGES
        if (rows := [s for s in stages if s.name == name])
        and all(s.status == StageStatus.SUCCEEDED for s in rows)
    }
    return next((name for name in STAGES if name not in done), None)


def rerun(
    sessions: SessionFactory,
    storage: Storage,
    send: Send,
    job_id: uuid.UUID,
    from_stage: str | None = None,
    params: dict | None = None,
) -> str:
    """Run a finished job again from `from_stage` (default: its first unfinished stage).

    Stages before `from_stage` keep their rows and artifacts; the later ones are reset
    (tracking chunks are planned afresh, since new parameters may change them).
    Returns the stage the run restarts from.
    """
    with transaction(sessions) as session:
        job = lock_job(session, job_id)
        if job is None:
            raise WorkflowError(f"job {job_id} does not exist")
        if job.status not in FINISHED_JOB:
            raise WorkflowError(f"job {job.id} is {job.status}; only a finished job can re-run")
        _require_uploaded(job)
        unfinished = default_rerun_stage(job.stages)
        start = from_stage or unfinished
        if start is None:
            raise WorkflowError(f"every stage of job {job.id} succeeded; name from_stage")
        if unfinished is not None and STAGES.index(unfinished) < STAGES.index(start):
            raise WorkflowError(
                f"stage {unfinished} of job {job.id} has not succeeded: re-run from it or earlier"
            )
        if params is not None:
            job.params = params
        stale_keys = _reset_from(session, job, start)
        if not job.stages:
            job.stages = static_stages()
        job.status, job.error, job.finished_at = JobStatus.QUEUED, None, None
    for key in stale_keys:
        storage.delete(key)
    advance(sessions, storage, send, job_id)
    return start


def _reset_from(session: Session, job: Job, start: str) -> list[str]:
    """Reset every stage from `start` on; return the storage keys of their stale outputs."""
    first = STAGES.index(start)
    reset = [s for s in job.stages if STAGES.index(s.name) >= first]
    reset_ids = {s.id for s in reset}
    stale = [a for a in job.artifacts if a.stage_id in reset_ids]
    for artifact in stale:
        session.delete(artifact)
    for stage in reset:
        if stage.name == "track":
            session.delete(stage)
        else:
            _reset(stage)
    session.flush()
    session.expire(job, ["stages", "artifacts"])
    return [a.storage_key for a in stale]


def _reset(stage: Stage) -> None:
    stage.status, stage.progress, stage.queue_token = StageStatus.PENDING, 0.0, None
    stage.deliveries, stage.error, stage.metrics, stage.warnings = 0, None, {}, []
    stage.queued_at = stage.started_at = stage.finished_at = None
