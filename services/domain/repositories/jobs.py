"""Queries on jobs, their input files, stages and artifacts."""

from __future__ import annotations

import uuid
from collections.abc import Iterable
from typing import Any

from sqlalchemy import select
from sqlalchemy.dialects.postgresql import insert
from sqlalchemy.orm import Session, joinedload, selectinload

from services.core.models import Artifact, Job, Night, Stage, Team


def get(session: Session, job_id: uuid.UUID | str) -> Job | None:
    """The job with its night, files and stages (one query per relation: pages poll this)."""
    loads = [joinedload(Job.night), selectinload(Job.files), selectinload(Job.stages)]
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


def listing(session: Session, status: str | None, limit: int) -> list[tuple[Job, Night, Team]]:
    """Jobs of every team with their night and team, most recently changed first."""
    query = select(Job, Night, Team).join(Job.night).join(Night.team)
    if status is not None:
        query = query.where(Job.status == status)
    rows = session.execute(query.order_by(Job.updated_at.desc()).limit(limit))
    return [(job, night, team) for job, night, team in rows]


def save_artifact(session: Session, values: dict[str, Any]) -> None:
    """Insert an artifact row, or update the job's row of the same name."""
    update = {k: values[k] for k in ("stage_id", "storage_key", "size", "content_type")}
    session.execute(
        insert(Artifact)
        .values(**values)
        .on_conflict_do_update(index_elements=["job_id", "name"], set_=update)
    )
