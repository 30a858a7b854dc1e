"""Running one unit of one job: state in PostgreSQL, files through object storage.

`execute` is what every stage task does: claim the stage row (token check, attempt and
delivery counts), download exactly what the unit reads (`pipeline.graph.reads`) and the
input videos it decodes into a temporary folder, run it (`pipeline.graph.execute`),
upload what it wrote under the job's deterministic keys, record metrics or the error,
and let `services.domain.workflow.advance` queue what follows. Errors are sorted into
three kinds: transient (storage or database unreachable, broker refused) → retried with
backoff up to ``max_attempts``; cancellation → the stage stops quietly; anything else →
the stage and the job fail with a readable message and nothing is retried.
"""

from __future__ import annotations

import logging
import mimetypes
import random
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from tempfile import TemporaryDirectory

from celery import Task
from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy.exc import DBAPIError, OperationalError
from sqlalchemy.orm import Session

from pipeline import graph
from pipeline.artifacts import PROBE_JSON
from pipeline.graph import StageResult, Unit
from pipeline.jsonio import json_safe
from pipeline.night import NightInfo
from pipeline.params import ProcessParams
from pipeline.probe import StereoProbe
from pipeline.summary import summarise
from services.core.db import SessionFactory, transaction
from services.core.models import Job, Stage, StageStatus
from services.core.settings import Settings
from services.core.storage import Storage, TransientStorageError
from services.domain import states, workflow
from services.domain.nights import night_info
from services.domain.repositories import jobs
from services.domain.workflow import EnqueueError, Send, job_key, unit_of
from services.worker.heartbeat import Heartbeat
from services.worker.inputs import InputCache, InputRef, fetch_artifact

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
class Claim:
    """A claimed delivery: everything its unit needs, read when the stage started."""

    job_id: str
    stage_id: int
    key: str
    unit: Unit
    token: str
    attempt: int
    deliveries: int
    params: ProcessParams
    separation_m: float
    height_m: float | None
    inputs: tuple[InputRef, ...]
    night: NightInfo = field(default_factory=NightInfo)


Progress = Callable[[float], None]
StageBody = Callable[[Claim, Path, "Runtime", Progress], StageResult]


def execute(
    task: Task, rt: Runtime, job_id: str, key: str, token: str, body: StageBody | None = None
) -> None:
    """Run one delivery of a stage task (see the module docstring).

    `body` runs the claimed unit in a working folder; `run_unit` unless given.
    """
    body = body or run_unit
    try:
        claimed = claim(rt, job_id, key, token)
    except TRANSIENT_ERRORS as exc:
        raise _retry(task, rt, None, exc) from exc
    if claimed is None:
        return
    try:
        rt.settings.work_dir.mkdir(parents=True, exist_ok=True)
        beat = Heartbeat(
            rt.sessions, rt.settings.heartbeat_interval_s, claimed.stage_id, claimed.token
        )
        with (
            beat,
            TemporaryDirectory(dir=rt.settings.work_dir, prefix=f"{claimed.unit.stage}-") as tmp,
        ):
            workdir = Path(tmp)
            result = body(claimed, workdir, rt, ProgressReporter(rt, claimed))
            _check_current(rt, claimed)
            uploaded = upload_outputs(rt.storage, claimed.job_id, workdir, result.outputs)
        succeed(rt, claimed, result, uploaded)
        with rt.sessions() as session:
            workflow.advance(session, rt.storage, rt.send, claimed.job_id)
    except StageCancelled:
        log.info("stage %s of job %s stopped: job no longer running", key, job_id)
        _stop(rt, claimed)
    except TRANSIENT_ERRORS as exc:
        raise _retry(task, rt, claimed, exc) from exc
    except SoftTimeLimitExceeded:
        fail_stage(rt, job_id, key, token, time_limit_message(rt.settings, claimed))
    except Exception as exc:
        log.exception("stage %s of job %s failed", key, job_id)
        fail_stage(rt, job_id, key, token, _message(exc))


def time_limit_message(settings: Settings, claimed: Claim) -> str:
    """Why a stage was stopped at the soft time limit, and which parameter to change."""
    limit = settings.task_soft_time_limit_s
    message = f"took longer than the {limit} s time limit (FIREFLY3D_TASK_SOFT_TIME_LIMIT_S)"
    if graph.stage(claimed.unit.stage).scope == "chunk":
        message += (
            f": re-run with a smaller chunk_s (now {claimed.params.chunk_s:g} s) so that "
            "each chunk fits"
        )
    return message


def run_unit(claimed: Claim, workdir: Path, rt: Runtime, progress: Progress) -> StageResult:
    """Fetch what the unit reads and the videos it decodes; run it in `workdir`."""
    entry = graph.stage(claimed.unit.stage)
    videos: dict[int, dict[int, Path]] = {}
    context = graph.StageContext(
        workdir=workdir,
        unit=claimed.unit,
        params=claimed.params,
        separation_m=claimed.separation_m,
        camera_height_m=claimed.height_m,
        night=claimed.night,
        videos=videos,
        progress=progress,
    )
    probed = PROBE_JSON in entry.reads
    if probed:  # first: the names of chunks depend on the plan it gives
        fetch_artifact(rt.storage, claimed.job_id, PROBE_JSON, workdir)
    chunked = any(graph.is_chunk_template(t) for t in entry.reads)
    units = context.units if chunked else graph.plan(None, claimed.params)
    for name in graph.reads(claimed.unit, units):
        if name != PROBE_JSON:
            fetch_artifact(rt.storage, claimed.job_id, name, workdir)
    videos.update(_fetch_videos(claimed, entry, context.probe if probed else None, workdir, rt))
    return graph.execute(entry, context)


def _fetch_videos(
    claimed: Claim, entry: graph.Stage, probe: StereoProbe | None, workdir: Path, rt: Runtime
) -> dict[int, dict[int, Path]]:
    """The input videos the unit decodes, verified, under their uploaded names."""
    refs: list[InputRef] = []
    if entry.videos == "all":
        refs = list(claimed.inputs)
    elif entry.videos == "chunk":
        assert probe is not None and claimed.unit.camera is not None
        chapters = graph.chunk_chapters(claimed.unit, probe, claimed.params)
        refs = [
            r for r in claimed.inputs if r.camera == claimed.unit.camera and r.chapter in chapters
        ]
    videos: dict[int, dict[int, Path]] = {}
    for ref in refs:
        # The team's own file name, so that the pipeline's error messages name it.
        dest = workdir / "input" / f"cam{ref.camera}" / f"{ref.chapter:02d}" / ref.filename
        videos.setdefault(ref.camera, {})[ref.chapter] = rt.cache.fetch(rt.storage, ref, dest)
    return videos


def _message(exc: BaseException) -> str:
    text = str(exc).strip()
    return text if text else type(exc).__name__


def claim(rt: Runtime, job_id: str, key: str, token: str) -> Claim | None:
    """Mark the stage running for this delivery; None if it must not run.

    A message whose token is not the row's is stale (the stage was reset or re-queued).
    A stage that already succeeded was delivered twice: only `advance` again, in case the
    first delivery stopped before queueing what follows.
    """
    with transaction(rt.sessions) as session:
        claimed = _claim_row(session, job_id, key, token)
    if claimed == DUPLICATE:
        with rt.sessions() as session:
            workflow.advance(session, rt.storage, rt.send, job_id)
        return None
    if not isinstance(claimed, Claim):
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


def _claim_row(session: Session, job_id: str, key: str, token: str) -> Claim | str | None:
    job = jobs.lock(session, job_id)
    stage = jobs.stage(session, job_id, key)
    if job is None or stage is None or stage.queue_token != token:
        return None
    if stage.status == StageStatus.SUCCEEDED:
        return DUPLICATE
    if job.status not in states.ACTIVE_JOB or stage.status not in (
        StageStatus.QUEUED,
        StageStatus.RUNNING,
    ):
        return None
    states.start_stage(stage)
    states.start_job(job)
    inputs = tuple(
        InputRef(
            f.camera,
            f.chapter,
            f.filename,
            f.storage_key,
            f.size,
            f.sha256,
            f.part_size,
            f.checksum,
        )
        for f in job.files
    )
    return Claim(
        job_id=str(job.id),
        stage_id=stage.id,
        key=stage.key,
        unit=unit_of(stage),
        token=str(stage.queue_token),
        attempt=stage.attempt,
        deliveries=stage.deliveries,
        params=ProcessParams.model_validate(job.params),
        separation_m=job.night.separation_m,
        height_m=job.night.height_m,
        inputs=inputs,
        night=night_info(job.night),
    )


class ProgressReporter:
    """Writes a stage's progress at most every ``progress_interval_s`` seconds.

    It is also where a running stage learns that its job was cancelled: it raises
    `StageCancelled` from inside the pipeline's progress callback.
    """

    def __init__(self, rt: Runtime, claimed: Claim) -> None:
        self.rt, self.claimed = rt, claimed
        self.last = time.monotonic()

    def __call__(self, fraction: float) -> None:
        if time.monotonic() - self.last < self.rt.settings.progress_interval_s:
            return
        self.last = time.monotonic()
        try:
            with transaction(self.rt.sessions) as session:
                stage = session.get(Stage, self.claimed.stage_id)
                if not _is_current(session, stage, self.claimed):
                    raise StageCancelled
                assert stage is not None
                stage.progress = min(max(float(fraction), 0.0), 1.0)
        except OperationalError:
            log.warning("could not record progress of %s", self.claimed.key, exc_info=True)


def _is_current(session: Session, stage: Stage | None, claimed: Claim) -> bool:
    job = session.get(Job, uuid.UUID(claimed.job_id))
    return (
        job is not None
        and job.status in states.ACTIVE_JOB
        and stage is not None
        and stage.queue_token == claimed.token
        and stage.status == StageStatus.RUNNING
    )


def _check_current(rt: Runtime, claimed: Claim) -> None:
    with transaction(rt.sessions) as session:
        if not _is_current(session, session.get(Stage, claimed.stage_id), claimed):
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


def succeed(rt: Runtime, claimed: Claim, result: StageResult, uploaded: list[Uploaded]) -> None:
    """Record the stage's success, its artifacts (upserted by name) and the job's summary."""
    with transaction(rt.sessions) as session:
        job = jobs.lock(session, claimed.job_id)
        stage = session.get(Stage, claimed.stage_id, with_for_update=True)
        if job is None or not _is_current(session, stage, claimed):
            raise StageCancelled
        assert stage is not None
        states.succeed_stage(stage, json_safe(result.metrics), [str(w) for w in result.warnings])
        for item in uploaded:
            jobs.save_artifact(
                session,
                {
                    "job_id": job.id,
                    "stage_id": stage.id,
                    "name": item.name,
                    "storage_key": item.storage_key,
                    "size": item.size,
                    "content_type": item.content_type,
                },
            )
        job.summary = json_safe(job_summary(job))


def job_summary(job: Job) -> dict:
    """The run summary (`pipeline.summary`) of a job's succeeded stages."""
    records = {
        unit_of(s): StageResult(metrics=s.metrics, warnings=s.warnings)
        for s in job.stages
        if s.status == StageStatus.SUCCEEDED and s.frame_start is None
    }
    return summarise(records, ProcessParams.model_validate(job.params))


def fail_stage(rt: Runtime, job_id: str, key: str, token: str, message: str) -> None:
    """Mark the stage failed with `message`; the job fails and says which stage and why."""
    with transaction(rt.sessions) as session:
        job = jobs.lock(session, job_id)
        stage = jobs.stage(session, job_id, key)
        if job is None or stage is None or stage.queue_token != token:
            return
        workflow.fail(job, stage, message)


def _stop(rt: Runtime, claimed: Claim) -> None:
    with transaction(rt.sessions) as session:
        stage = session.get(Stage, claimed.stage_id, with_for_update=True)
        if stage is not None and stage.queue_token == claimed.token:
            states.stop_stage(stage, "stopped: the job is no longer running")


def backoff_s(settings: Settings, attempt: int) -> float:
    """Exponential backoff with jitter: about base·2^(attempt−1), capped."""
    delay = min(settings.retry_backoff_max_s, settings.retry_backoff_s * 2 ** max(attempt - 1, 0))
    return delay * random.uniform(0.5, 1.0)


def _retry(task: Task, rt: Runtime, claimed: Claim | None, exc: BaseException) -> BaseException:
    """Schedule another delivery after a transient error, or fail once attempts run out."""
    attempt = claimed.deliveries if claimed else task.request.retries + 1
    if attempt >= rt.settings.max_attempts:
        if claimed is not None:
            message = f"gave up after {attempt} attempts; last error: {_message(exc)}"
            _record_quietly(
                lambda: fail_stage(rt, claimed.job_id, claimed.key, claimed.token, message)
            )
        return exc
    delay = backoff_s(rt.settings, attempt)
    if claimed is not None:
        note = f"attempt {attempt}: {_message(exc)}; retrying in {delay:.0f} s"
        _record_quietly(lambda: _requeue(rt, claimed, note))
    log.warning("transient error, retrying in %.0f s: %s", delay, exc)
    return task.retry(exc=exc, countdown=delay, max_retries=None)


def _requeue(rt: Runtime, claimed: Claim, note: str) -> None:
    with transaction(rt.sessions) as session:
        stage = session.get(Stage, claimed.stage_id, with_for_update=True)
        if stage is not None and stage.queue_token == claimed.token:
            states.retry_stage(stage, note)


def _record_quietly(action: Callable[[], None]) -> None:
    # The error being handled may be the database itself being down.
    try:
        action()
    except (OperationalError, DBAPIError):
        log.warning("could not record the stage's state", exc_info=True)
