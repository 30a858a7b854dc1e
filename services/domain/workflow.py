"""A job's stage graph in PostgreSQL: which units exist, which may run now, re-runs.

The graph is `pipeline.graph.STAGES`; each of its units is a stage row of the job.
Whole-run and per-camera rows are created at submission; tracking chunks once the
probe has succeeded (planning needs the cameras' lengths). `advance` is the only place
that queues stages: under the job's row lock it queues every pending row whose
prerequisites have succeeded, each with a fresh token, commits, and only then hands the
messages to the broker (enqueue after commit). Tasks carry that token, so a stale or
duplicated message finds a different token, or a finished stage, and does nothing.

Every status change goes through `services.domain.states`.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session

from pipeline import graph
from pipeline.artifacts import PROBE_JSON
from pipeline.params import ProcessParams
from pipeline.probe import StereoProbe
from services.core.models import Job, JobStatus, Stage, StageStatus, UploadState
from services.core.storage import Storage
from services.domain import states
from services.domain.errors import Conflict, NotFound, Unavailable
from services.domain.repositories import jobs


class EnqueueError(Unavailable):
    """The broker did not take the messages; the stages went back to pending."""


@dataclass(frozen=True)
class StageMessage:
    """What a worker needs to find its stage row: sent as the task's arguments."""

    job_id: str
    key: str
    name: str
    token: str


Send = Callable[[list[StageMessage]], None]


def job_key(job_id: uuid.UUID | str, name: str) -> str:
    """Storage key of a job's artifact or input (``name`` relative to the job folder)."""
    return f"jobs/{job_id}/{name}"


def unit_of(stage: Stage) -> graph.Unit:
    """The graph unit a stage row stands for."""
    return graph.Unit(stage.name, stage.camera, stage.frame_start, stage.frame_stop)


def new_stage(unit: graph.Unit) -> Stage:
    """A pending stage row (every column set: `advance` reads them before a flush)."""
    return Stage(
        key=unit.key,
        name=unit.stage,
        camera=unit.camera,
        frame_start=unit.start,
        frame_stop=unit.stop,
        status=StageStatus.PENDING,
        attempt=0,
        deliveries=0,
        progress=0.0,
        metrics={},
        warnings=[],
    )


def locked(session: Session, job_id: uuid.UUID | str) -> Job:
    """The job, locked (`jobs.lock`).

    Raises
    ------
    NotFound
        If there is no such job.
    """
    job = jobs.lock(session, job_id)
    if job is None:
        raise NotFound(f"job {job_id} does not exist")
    return job


def load_probe(storage: Storage, job_id: uuid.UUID | str) -> StereoProbe:
    """The probe result a job's probe stage stored."""
    return StereoProbe.from_dict(json.loads(storage.read_bytes(job_key(job_id, PROBE_JSON))))


def _plan_missing(job: Job, storage: Storage) -> list[Stage]:
    """Rows for the units not planned yet that can be planned now.

    A new job gets its whole-run and per-camera units; chunk units follow once the
    probe has succeeded (its `probe.json` gives the cameras' lengths).
    """
    params = ProcessParams.model_validate(job.params)
    if not job.stages:
        return [new_stage(u) for u in graph.plan(None, params)]
    planned = {s.name for s in job.stages}
    unplanned = [e.name for e in graph.STAGES if e.scope == "chunk" and e.name not in planned]
    planner = graph.producer(PROBE_JSON).name
    probe_rows = [s for s in job.stages if s.name == planner]
    probed = bool(probe_rows) and all(s.status == StageStatus.SUCCEEDED for s in probe_rows)
    if not unplanned or not probed:
        return []
    existing = {s.key for s in job.stages}
    units = graph.plan(load_probe(storage, job.id), params)
    return [new_stage(u) for u in units if u.key not in existing]


def ready(stages: list[Stage]) -> list[Stage]:
    """Pending stages whose prerequisites have all succeeded."""
    rows = {s.key: s for s in stages}
    units = [unit_of(s) for s in stages]

    def can_run(stage: Stage) -> bool:
        needed = graph.prerequisites(unit_of(stage), units)
        return needed is not None and all(
            rows[u.key].status == StageStatus.SUCCEEDED for u in needed
        )

    return [s for s in stages if s.status == StageStatus.PENDING and can_run(s)]


def advance(session: Session, storage: Storage, send: Send, job_id: uuid.UUID | str) -> None:
    """Queue whatever can run now; mark the job succeeded when every stage has.

    Commits. Raises `EnqueueError` if the broker refused the messages (the stages are
    pending again, so a later `advance` or an admin re-run queues them).
    """
    job = jobs.lock(session, job_id)
    if job is None or job.status not in states.ACTIVE_JOB:
        session.commit()
        return
    job.stages.extend(_plan_missing(job, storage))
    if all(s.status == StageStatus.SUCCEEDED for s in job.stages):
        states.finish_job(job, JobStatus.SUCCEEDED)
        session.commit()
        return
    messages = [
        StageMessage(str(job.id), stage.key, stage.name, states.queue_stage(stage))
        for stage in ready(job.stages)
    ]
    session.commit()
    send_or_revert(session, send, messages)


def send_or_revert(session: Session, send: Send, messages: list[StageMessage]) -> None:
    """Publish committed messages; if the broker refuses, their stages go back to pending."""
    if not messages:
        return
    try:
        send(messages)
    except Exception as exc:
        for stage in jobs.stages_with_tokens(session, [m.token for m in messages]):
            if stage.status == StageStatus.QUEUED:
                states.unqueue_stage(stage)
        session.commit()
        raise EnqueueError(f"the task broker did not accept the job's stages: {exc}") from exc


def _require_uploaded(job: Job) -> None:
    missing = [
        f"camera {f.camera} chapter {f.chapter} ({f.filename})"
        for f in job.files
        if f.upload_state != UploadState.UPLOADED
    ]
    if missing:
        raise Conflict(f"not uploaded yet: {', '.join(missing)}")


def submit(session: Session, storage: Storage, send: Send, job_id: uuid.UUID) -> None:
    """Queue a job whose inputs are all uploaded (commits)."""
    job = locked(session, job_id)
    if job.status not in (JobStatus.CREATED, JobStatus.UPLOADING):
        raise Conflict(f"job {job.id} is {job.status}; only a new job can be submitted")
    _require_uploaded(job)
    if not job.stages:
        job.stages = _plan_missing(job, storage)
    states.submit_job(job)
    session.commit()
    advance(session, storage, send, job_id)


def cancel(session: Session, job_id: uuid.UUID) -> None:
    """Cancel a job that has not finished (commits); running stages stop at their next
    progress report."""
    job = locked(session, job_id)
    if job.status in states.FINISHED_JOB:
        raise Conflict(f"job {job.id} already finished ({job.status})")
    states.finish_job(job, JobStatus.CANCELLED, "cancelled by the team")
    session.commit()


def fail(job: Job, stage: Stage, message: str) -> None:
    """Fail `stage` with `message`; the job fails and says which stage and why."""
    states.fail_stage(stage, message)
    if job.status in states.ACTIVE_JOB:
        states.finish_job(job, JobStatus.FAILED, f"{unit_of(stage).label} failed: {message}")


def first_incomplete(stages: Iterable[Stage], written: Collection[str]) -> tuple[str, str] | None:
    """The first stage, in pipeline order, to run again, and why; None if none need to.

    A stage needs to when one of its units has not succeeded, or when it succeeded
    without writing a file that some unit reads (it ran under an earlier release, which
    wrote fewer files): `written` names the job's artifacts.
    """
    stages = list(stages)
    units = [unit_of(s) for s in stages]
    unwritten: dict[str, str] = {}
    for unit in units:
        for template in graph.stage(unit.stage).reads:
            if template == graph.EARLIER_METRICS:
                continue
            lacking = [n for n in graph.resolve(template, unit, units) if n not in written]
            if lacking:
                unwritten.setdefault(graph.producer(template).name, lacking[0])
    for name in graph.STAGE_NAMES:
        rows = [s for s in stages if s.name == name]
        if not rows or any(s.status != StageStatus.SUCCEEDED for s in rows):
            return name, "has not succeeded"
        if name in unwritten:
            return name, (
                f"did not write {unwritten[name]}, which later stages read "
                "(it ran under an earlier release)"
            )
    return None


def rerun(
    session: Session,
    storage: Storage,
    send: Send,
    job_id: uuid.UUID,
    from_stage: str | None = None,
    params: dict[str, Any] | None = None,
) -> str:
    """Run a finished job again from `from_stage` (default: its first unfinished stage).

    Stages before `from_stage` keep their rows and artifacts; the later ones are reset
    (tracking chunks are planned afresh, since new parameters may change them).
    Commits; returns the stage the run restarts from.
    """
    job = locked(session, job_id)
    if job.status not in states.FINISHED_JOB:
        raise Conflict(f"job {job.id} is {job.status}; only a finished job can re-run")
    _require_uploaded(job)
    incomplete = first_incomplete(job.stages, {a.name for a in job.artifacts})
    start = from_stage or (incomplete[0] if incomplete else None)
    if start is None:
        raise Conflict(f"every stage of job {job.id} succeeded; name from_stage")
    order = graph.STAGE_NAMES
    if incomplete is not None and order.index(incomplete[0]) < order.index(start):
        unfinished, why = incomplete
        raise Conflict(f"stage {unfinished} of job {job.id} {why}: re-run from it or earlier")
    if params is not None:
        job.params = params
    stale_keys = _reset_from(session, job, start)
    if not job.stages:  # cancelled before it was ever submitted
        job.stages = _plan_missing(job, storage)
    job.stages.extend(_added_since(job, start))
    states.requeue_job(job)
    session.commit()
    for key in stale_keys:
        storage.delete(key)
    advance(session, storage, send, job_id)
    return start


def _added_since(job: Job, start: str) -> list[Stage]:
    """Rows for the whole-run and per-camera units from `start` on that the job lacks:
    stages added by a later release than the one that ran it."""
    existing = {s.key for s in job.stages}
    first = graph.STAGE_NAMES.index(start)
    units = graph.plan(None, ProcessParams.model_validate(job.params))
    return [
        new_stage(u)
        for u in units
        if u.key not in existing and graph.STAGE_NAMES.index(u.stage) >= first
    ]


def _reset_from(session: Session, job: Job, start: str) -> list[str]:
    """Reset every stage from `start` on; return the storage keys of their stale outputs.

    Chunk rows are deleted rather than reset: they are planned again.
    """
    first = graph.STAGE_NAMES.index(start)
    reset = [s for s in job.stages if graph.STAGE_NAMES.index(s.name) >= first]
    reset_ids = {s.id for s in reset}
    stale = [a for a in job.artifacts if a.stage_id in reset_ids]
    for artifact in stale:
        session.delete(artifact)
    for stage in reset:
        if graph.stage(stage.name).scope == "chunk":
            job.stages.remove(stage)
            session.delete(stage)
        else:
            states.reset_stage(stage)
    session.flush()
    session.expire(job, ["artifacts"])
    return [a.storage_key for a in stale]


def progress(stages: Iterable[Stage]) -> float:
    """Fraction of the pipeline done: each stage counts equally, its units averaged."""
    stages = list(stages)

    def done(stage: Stage) -> float:
        return 1.0 if stage.status == StageStatus.SUCCEEDED else stage.progress

    fractions = []
    for name in graph.STAGE_NAMES:
        rows = [s for s in stages if s.name == name]
        fractions.append(sum(map(done, rows)) / len(rows) if rows else 0.0)
    return sum(fractions) / len(graph.STAGE_NAMES)
