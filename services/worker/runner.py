"""Running one stage of one job: state in PostgreSQL, files through object storage.

`execute` is what every stage task does: claim the stage row (token check, attempt and
delivery counts), download the stage's inputs into a temporary folder, call the
pipeline's stage function, upload what it wrote under the job's deterministic keys,
record metrics or the error, and let `services.core.workflow.advance` queue what
follows. Errors are sorted into three kinds: transient (storage or database
unreachable, broker refused) → retried with backoff up to ``max_attempts``;
cancellation → the stage stops quietly; anything else → the stage and the job fail
with a readable message and nothing is retried.
"""

from __future__ import annotations

import json
import logging
import math
import mimetypes
import random
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

from celery import Task
from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy import select
from sqlalchemy.dialects.postgresql import insert
from sqlalchemy.exc import DBAPIError, OperationalError
from sqlalchemy.orm import Session

from pipeline.run import ProcessParams, StageResult
from services.core.db import SessionFactory, transaction
from services.core.models import Artifact, Job, JobStatus, Stage, StageStatus
from services.core.settings import Settings
from services.core.storage import Storage, TransientStorageError
from services.core.workflow import (
    ACTIVE_JOB,
    EnqueueError,
    Send,
    advance,
    job_key,
    lock_job,
    now,
    stop_job,
)
from services.worker.inputs import InputCache, InputRef

log = logging.getLogger(__name__)

TRANSIENT_ERRORS: tuple[type[BaseException], ...] = (
    TransientStorageError,
    OperationalError,
    EnqueueError,
)


class StageCancelled(Exception):
    """The job was cancelled or failed elsewhere, or the stage was reset: stop."""


@dataclass(frozen=True)
class Runtime:
    """Per-process connections of a worker."""

    settings: Settings
    sessions: SessionFactory
    storage: Storage
    send: Send
    cache: InputCache


@dataclass(frozen=True)
class StageContext:
    """Everything a stage body needs, read from the database when the stage starts."""

    job_id: str
    stage_id: int
    key: str
    name: str
    token: str
    camera: int | None
    start: int | None
    stop: int | None
    attempt: int
    deliveries: int
    params: ProcessParams
    separation_m: float
    height_m: float | None
    inputs: tuple[InputRef, ...]


Progress = Callable[[float], None]
StageBody = Callable[[StageContext, Path, Runtime, Progress], StageResult]


def describe(stage: Stage) -> str:
    """Readable name of a stage row, e.g. ``track camera 1 frames 0–1800``."""
    if stage.name == "track":
        return f"track camera {stage.camera} frames {stage.frame_start}–{stage.frame_stop}"
    return stage.name if stage.camera is None else f"{stage.name} camera {stage.camera}"


def execute(task: Task, rt: Runtime, body: StageBody, job_id: str, key: str, token: str) -> None:
    """Run one delivery of a stage task (see the module docstring)."""
    try:
        ctx = claim(rt, job_id, key, token)
    except TRANSIENT_ERRORS as exc:
        raise _retry(task, rt, None, exc) from exc
    if ctx is None:
        return
    try:
        rt.settings.work_dir.mkdir(parents=True, exist_ok=True)
        with TemporaryDirectory(dir=rt.settings.work_dir, prefix=f"{ctx.name}-") as tmp:
            workdir = Path(tmp)
            result = body(ctx, workdir, rt, ProgressReporter(rt, ctx))
            _check_current(rt, ctx)
            uploaded = upload_outputs(rt.storage, ctx.job_id, workdir, result.outputs)
        succeed(rt, ctx, result, uploaded)
        advance(rt.sessions, rt.storage, rt.send, ctx.job_id)
    except StageCancelled:
        log.info("stage %s of job %s stopped: job no longer running", key, job_id)
        _finish_stage(rt, ctx, StageStatus.CANCELLED, "stopped: the job is no longer running")
    except TRANSIENT_ERRORS as exc:
        raise _retry(task, rt, ctx, exc) from exc
    except SoftTimeLimitExceeded:
        limit = rt.settings.task_soft_time_limit_s
        fail_stage(rt, job_id, key, token, f"took longer than the {limit} s time limit")
    except Exception as exc:
        log.exception("stage %s of job %s failed", key, job_id)
        fail_stage(rt, job_id, key, token, _message(exc))


def _message(exc: BaseException) -> str:
    text = str(exc).strip()
    return text if text else type(exc).__name__


def claim(rt: Runtime, job_id: str, key: str, token: str) -> StageContext | None:
    """Mark the stage running for this delivery; None if it must not run.

    A message whose token is not the row's is stale (the stage was reset or re-queued).
    A stage that already succeeded was delivered twice: only `advance` again, in case the
    first delivery stopped before queueing what follows.
    """
    with transaction(rt.sessions) as session:
        claimed = _claim_row(session, rt, job_id, key, token)
    if claimed == DUPLICATE:
        advance(rt.sessions, rt.storage, rt.send, job_id)
        return None
    if not isinstance(claimed, StageContext):
        return None
    if claimed.deliveries > rt.settings.max_attempts:
        message = (
            f"gave up after {rt.settings.max_attempts} attempts: the worker running it was "
            "lost each time (crash, out of memory or killed)"
        )
        fail_stage(rt, job_id, key, token, message)
        return None
    return claimed


DUPLICATE = "duplicate"


def _claim_row(
    session: Session, rt: Runtime, job_id: str, key: str, token: str
) -> StageContext | str | None:
    job = lock_job(session, job_id)
    stage = _stage(session, job_id, key)
    if job is None or stage is None or stage.queue_token != token:
        return None
    if stage.status == StageStatus.SUCCEEDED:
        return DUPLICATE
    if job.status not in ACTIVE_JOB or stage.status not in (
        StageStatus.QUEUED,
        StageStatus.RUNNING,
    ):
        return None
    return _start(rt, job, stage)


def _stage(session: Session, job_id: str, key: str) -> Stage | None:
    query = select(Stage).where(Stage.job_id == uuid.UUID(job_id), Stage.key == key)
    return session.scalars(query.with_for_update()).one_or_none()


def _start(rt: Runtime, job: Job, stage: Stage) -> StageContext:
    if stage.status == StageStatus.RUNNING:
        stage.warnings = [*stage.warnings, f"attempt {stage.attempt}: the worker was lost"]
    stage.status, stage.started_at, stage.finished_at = StageStatus.RUNNING, now(), None
    stage.attempt += 1
    stage.deliveries += 1
    stage.progress = 0.0
    if job.status == JobStatus.QUEUED:
        job.status = JobStatus.RUNNING
        job.started_at = job.started_at or now()
    inputs = tuple(
        InputRef(f.camera, f.chapter, f.filename, f.storage_key, f.size, f.sha256)
        for f in job.files
    )
    return StageContext(
        job_id=str(job.id),
        stage_id=stage.id,
        key=stage.key,
        name=stage.name,
        token=str(stage.queue_token),
        camera=stage.camera,
        start=stage.frame_start,
        stop=stage.frame_stop,
        attempt=stage.attempt,
        deliveries=stage.deliveries,
        params=ProcessParams.model_validate(job.params),
        separation_m=job.night.separation_m,
        height_m=job.night.height_m,
        inputs=inputs,
    )


class ProgressReporter:
    """Writes a stage's progress at most every ``progress_interval_s`` seconds.

    It is also where a running stage learns that its job was cancelled: it raises
    `StageCancelled` from inside the pipeline's progress callback.
    """

    def __init__(self, rt: Runtime, ctx: StageContext) -> None:
        self.rt, self.ctx = rt, ctx
        self.last = time.monotonic()

    def __call__(self, fraction: float) -> None:
        if time.monotonic() - self.last < self.rt.settings.progress_interval_s:
            return
        self.last = time.monotonic()
        try:
            with transaction(self.rt.sessions) as session:
                stage = session.get(Stage, self.ctx.stage_id)
                if not _is_current(session, stage, self.ctx):
                    raise StageCancelled
                assert stage is not None
                stage.progress = min(max(float(fraction), 0.0), 1.0)
        except OperationalError:
            log.warning("could not record progress of %s", self.ctx.key, exc_info=True)


def _is_current(session: Session, stage: Stage | None, ctx: StageContext) -> bool:
    job = session.get(Job, uuid.UUID(ctx.job_id))
    return (
        job is not None
        and job.status in ACTIVE_JOB
        and stage is not None
        and stage.queue_token == ctx.token
        and stage.status == StageStatus.RUNNING
    )


def _check_current(rt: Runtime, ctx: StageContext) -> None:
    with transaction(rt.sessions) as session:
        if not _is_current(session, session.get(Stage, ctx.stage_id), ctx):
            raise StageCancelled


@dataclass(frozen=True)
class Uploaded:
    name: str
    storage_key: str
    size: int
    content_type: str


def upload_outputs(
    storage: Storage, job_id: str, workdir: Path, outputs: list[str]
) -> list[Uploaded]:
    """Upload a stage's outputs (files, or folders of files) under the job's keys."""
    files = []
    for name in outputs:
        path = workdir / name
        files += sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    uploaded = []
    for path in files:
        name = path.relative_to(workdir).as_posix()
        content_type = mimetypes.guess_type(name)[0] or "application/octet-stream"
        storage.upload_file(path, job_key(job_id, name), content_type)
        uploaded.append(Uploaded(name, job_key(job_id, name), path.stat().st_size, content_type))
    return uploaded


def json_safe(value: Any) -> Any:
    """`value` as plain JSON (numpy scalars to numbers, NaN and infinities to null)."""

    def default(obj: Any) -> Any:
        if hasattr(obj, "tolist"):
            return obj.tolist()
        return str(obj)

    def finite(obj: Any) -> Any:
        if isinstance(obj, float):
            return obj if math.isfinite(obj) else None
        if isinstance(obj, dict):
            return {str(k): finite(v) for k, v in obj.items()}
        if isinstance(obj, list):
            return [finite(v) for v in obj]
        return obj

    return finite(json.loads(json.dumps(value, default=default, allow_nan=True)))


def succeed(rt: Runtime, ctx: StageContext, result: StageResult, uploaded: list[Uploaded]) -> None:
    """Record the stage's success and its artifacts (one row per name, upserted)."""
    with transaction(rt.sessions) as session:
        lock_job(session, ctx.job_id)
        stage = session.get(Stage, ctx.stage_id, with_for_update=True)
        if not _is_current(session, stage, ctx):
            raise StageCancelled
        assert stage is not None
        stage.status, stage.progress, stage.finished_at = StageStatus.SUCCEEDED, 1.0, now()
        stage.metrics = json_safe(result.metrics)
        stage.warnings = [*stage.warnings, *map(str, result.warnings)]
        stage.error = None
        for item in uploaded:
            values = {
                "job_id": uuid.UUID(ctx.job_id),
                "stage_id": ctx.stage_id,
                "name": item.name,
                "storage_key": item.storage_key,
                "size": item.size,
                "content_type": item.content_type,
            }
            update = {k: values[k] for k in ("stage_id", "storage_key", "size", "content_type")}
            session.execute(
                insert(Artifact)
                .values(**values)
                .on_conflict_do_update(index_elements=["job_id", "name"], set_=update)
            )


def fail_stage(rt: Runtime, job_id: str, key: str, token: str, message: str) -> None:
    """Mark the stage failed with `message`; the job fails and says which stage and why."""
    with transaction(rt.sessions) as session:
        job = lock_job(session, job_id)
        stage = _stage(session, job_id, key)
        if job is None or stage is None or stage.queue_token != token:
            return
        stage.status, stage.error, stage.finished_at = StageStatus.FAILED, message, now()
        if job.status in ACTIVE_JOB:
            stop_job(job, JobStatus.FAILED, f"{describe(stage)} failed: {message}")


def _finish_stage(rt: Runtime, ctx: StageContext, status: StageStatus, error: str) -> None:
    with transaction(rt.sessions) as session:
        stage = session.get(Stage, ctx.stage_id, with_for_update=True)
        if stage is not None and stage.queue_token == ctx.token:
            stage.status, stage.error, stage.finished_at = status, error, now()


def backoff_s(settings: Settings, attempt: int) -> float:
    """Exponential backoff with jitter: about base·2^(attempt−1), capped."""
    delay = min(settings.retry_backoff_max_s, settings.retry_backoff_s * 2 ** max(attempt - 1, 0))
    return delay * random.uniform(0.5, 1.0)


def _retry(task: Task, rt: Runtime, ctx: StageContext | None, exc: BaseException) -> BaseException:
    """Schedule another delivery after a transient error, or fail once attempts run out."""
    attempt = ctx.deliveries if ctx else task.request.retries + 1
    if attempt >= rt.settings.max_attempts:
        if ctx is not None:
            message = f"gave up after {attempt} attempts; last error: {_message(exc)}"
            _record_quietly(lambda: fail_stage(rt, ctx.job_id, ctx.key, ctx.token, message))
        return exc
    delay = backoff_s(rt.settings, attempt)
    if ctx is not None:
        note = f"attempt {attempt}: {_message(exc)}; retrying in {delay:.0f} s"
        _record_quietly(lambda: _requeue(rt, ctx, note))
    log.warning("transient error, retrying in %.0f s: %s", delay, exc)
    return task.retry(exc=exc, countdown=delay, max_retries=None)


def _requeue(rt: Runtime, ctx: StageContext, note: str) -> None:
    with transaction(rt.sessions) as session:
        stage = session.get(Stage, ctx.stage_id, with_for_update=True)
        if stage is not None and stage.queue_token == ctx.token:
            stage.status, stage.error = StageStatus.QUEUED, note


def _record_quietly(action: Callable[[], None]) -> None:
    # The error being handled may be the database itself being down.
    try:
        action()
    except (OperationalError, DBAPIError):
        log.warning("could not record the stage's state", exc_info=True)
