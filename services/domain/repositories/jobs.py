"""Queries on jobs, their input files, stages and artifacts."""

from __future__ import annotations

import uuid
from collections.abc import Iterable
from typing import Any

from sqlalchemy import Float, cast, func, select, text, update
from sqlalchemy.dialects.postgresql import insert
from sqlalchemy.orm import Session, joinedload, selectinload

from services.core.models import Artifact, Job, JobStatus, Night, Stage, StageStatus, Team


def get(session: Session, job_id: uuid.UUID | str) -> Job | None:
    """The job with its night, files and stages (one query per relation: pages poll this)."""
    loads = [
        joinedload(Job.night).joinedload(Night.team),
        selectinload(Job.files),
        selectinload(Job.stages),
    ]
    return session.get(Job, uuid.UUID(str(job_id)), options=loads)


def lock(session: Session, job_id: uuid.UUID | str) -> Job | None:
    """The job row locked until the transaction ends, read afresh with its files and stages.

    Every change of a job's state happens under this lock, which serialises the API and
    the workers acting on one job.
    """
    query = (
        select(Job)
        .where(Job.id == uuid.UUID(str(job_id)))
        .with_for_update(of=Job)
        .options(selectinload(Job.files), selectinload(Job.stages))
        .execution_options(populate_existing=True)
    )
    return session.scalars(query).one_or_none()


def stage(session: Session, job_id: uuid.UUID | str, key: str) -> Stage | None:
    """A stage row by its key, locked."""
    query = select(Stage).where(Stage.job_id == uuid.UUID(str(job_id)), Stage.key == key)
    return session.scalars(query.with_for_update()).one_or_none()


def stages_with_tokens(session: Session, tokens: Iterable[str]) -> list[Stage]:
    return list(session.scalars(select(Stage).where(Stage.queue_token.in_(list(tokens)))))


def _stalled_since(stall_limit_s: float) -> Any:
    """When the job's work last stalled (NULL: it has not): a silent stage (the sweeper
    has not run yet), or a stage the sweeper re-queued that no worker has taken since."""
    requeued = (Stage.status == StageStatus.QUEUED) & Stage.stalled_at.is_not(None)
    last = func.coalesce(Stage.heartbeat_at, Stage.started_at)
    return (
        select(func.max(func.coalesce(Stage.stalled_at, last)))
        .where(Stage.job_id == Job.id, _silent(stall_limit_s) | requeued)
        .correlate(Job)
        .scalar_subquery()
    )


STALLED = "stalled"


def listing(
    session: Session, status: str | None, limit: int, stall_limit_s: float
) -> list[tuple[Job, Night, Team, Any]]:
    """Jobs of every team with their night, team and when they stalled (or None), most
    recently changed first. `status` is a job status, or "stalled": active jobs whose
    work stalled."""
    stalled = _stalled_since(stall_limit_s)
    query = select(Job, Night, Team, stalled).join(Job.night).join(Night.team)
    if status == STALLED:
        query = query.where(Job.status.in_(ACTIVE), stalled.is_not(None))
    elif status is not None:
        query = query.where(Job.status == status)
    rows = session.execute(query.order_by(Job.updated_at.desc()).limit(limit))
    return [(job, night, team, when) for job, night, team, when in rows]


def save_artifact(session: Session, values: dict[str, Any]) -> None:
    """Insert an artifact row, or update the job's row of the same name."""
    update = {k: values[k] for k in ("stage_id", "storage_key", "size", "content_type")}
    session.execute(
        insert(Artifact)
        .values(**values)
        .on_conflict_do_update(index_elements=["job_id", "name"], set_=update)
    )


ACTIVE = (JobStatus.QUEUED, JobStatus.RUNNING)


def beat(session: Session, stage_id: int, token: str) -> bool:
    """Record a sign of life of a running stage's delivery; False if it is no longer its own.

    The database's clock is the only clock: workers on other machines may drift.
    """
    result = session.execute(
        update(Stage)
        .where(
            Stage.id == stage_id,
            Stage.queue_token == token,
            Stage.status == StageStatus.RUNNING,
        )
        .values(heartbeat_at=func.now())
    )
    return bool(getattr(result, "rowcount", 0))


def beat_reserved(session: Session, tokens: Iterable[str]) -> set[str]:
    """Record that a worker holds these stages' messages (not started yet); returns the
    tokens whose stages are still queued (the others started, or were reset)."""
    result = session.execute(
        update(Stage)
        .where(Stage.queue_token.in_(list(tokens)), Stage.status == StageStatus.QUEUED)
        .values(heartbeat_at=func.now())
        .returning(Stage.queue_token)
    )
    return {str(token) for token in result.scalars()}


def _older_than(column: Any, seconds: float) -> Any:
    return column < func.now() - func.make_interval(0, 0, 0, 0, 0, 0, seconds)


def _silent(limit_s: float) -> Any:
    """A stage whose worker fell silent: running without a heartbeat for `limit_s`, or
    queued with a message a worker took (and beat for) but stopped beating for."""
    running = (Stage.status == StageStatus.RUNNING) & _older_than(
        func.coalesce(Stage.heartbeat_at, Stage.started_at, Stage.queued_at), limit_s
    )
    held = (Stage.status == StageStatus.QUEUED) & _older_than(Stage.heartbeat_at, limit_s)
    return running | held


def stalled(
    session: Session, limit_s: float, job_id: uuid.UUID | None = None
) -> list[tuple[uuid.UUID, int, float]]:
    """``(job id, stage id, seconds silent)`` of the silent stages of active jobs (by the
    database's clock)."""
    last = func.coalesce(Stage.heartbeat_at, Stage.started_at, Stage.queued_at)
    silent = cast(func.extract("epoch", func.now() - last), Float)
    query = (
        select(Stage.job_id, Stage.id, silent)
        .join(Job, Job.id == Stage.job_id)
        .where(Job.status.in_(ACTIVE), _silent(limit_s))
    )
    if job_id is not None:
        query = query.where(Stage.job_id == job_id)
    return [(j, s, float(t)) for j, s, t in session.execute(query)]


def idle_active(session: Session, quiet_s: float) -> list[uuid.UUID]:
    """Active jobs with no stage queued or running and no change for `quiet_s`: an
    enqueue that failed left them waiting for an `advance` nobody will call. (The quiet
    time keeps the sweep out of a transition that is still under way.)"""
    busy = select(Stage.id).where(
        Stage.job_id == Job.id, Stage.status.in_((StageStatus.QUEUED, StageStatus.RUNNING))
    )
    cutoff = func.now() - func.make_interval(0, 0, 0, 0, 0, 0, quiet_s)
    recent = select(Stage.id).where(
        Stage.job_id == Job.id,
        (Stage.finished_at > cutoff) | (Stage.queued_at > cutoff),
    )
    query = select(Job.id).where(
        Job.status.in_(ACTIVE), Job.updated_at < cutoff, ~busy.exists(), ~recent.exists()
    )
    return list(session.scalars(query))


def try_advisory_lock(session: Session, key: int) -> bool:
    """Take a transaction-scoped advisory lock if nobody holds it (one sweeper at a time)."""
    return bool(session.scalar(text("SELECT pg_try_advisory_xact_lock(:key)"), {"key": key}))


#: One statement: the job's team and a digest of the row versions (PostgreSQL's xmin,
#: new on every update) of the job, its night, stages and files. Any change to what a
#: status shows changes it; nothing else has to remember to bump a counter.
VERSION = text(
    """
    SELECT n.team_id, md5(concat_ws(':', j.xmin::text, n.xmin::text,
        (SELECT string_agg(s.id::text || '.' || s.xmin::text, ',' ORDER BY s.id)
           FROM stages s WHERE s.job_id = j.id),
        (SELECT string_agg(f.id::text || '.' || f.xmin::text, ',' ORDER BY f.id)
           FROM input_files f WHERE f.job_id = j.id)))
      FROM jobs j JOIN nights n ON n.id = j.night_id
     WHERE j.id = :job_id
    """
)


def version(session: Session, job_id: uuid.UUID) -> tuple[uuid.UUID, str] | None:
    """``(team id, version)`` of a job, or None: see `VERSION`."""
    row = session.execute(VERSION, {"job_id": job_id}).one_or_none()
    return None if row is None else (row[0], row[1])


def active_count(session: Session, team_id: uuid.UUID) -> int:
    """A team's jobs queued or running (for the concurrent-jobs quota)."""
    query = (
        select(func.count())
        .select_from(Job)
        .join(Night)
        .where(Night.team_id == team_id, Job.status.in_(ACTIVE))
    )
    return int(session.scalar(query) or 0)
