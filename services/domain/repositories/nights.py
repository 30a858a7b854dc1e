"""Queries on nights."""

from __future__ import annotations

import uuid

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from services.core.models import InputFile, Job, Night


def get(session: Session, night_id: uuid.UUID) -> Night | None:
    return session.get(Night, night_id)


def of_team(session: Session, team_id: uuid.UUID) -> list[Night]:
    """A team's nights, latest first."""
    query = select(Night).where(Night.team_id == team_id)
    return list(session.scalars(query.order_by(Night.date.desc(), Night.created_at)))


def job_ids(session: Session, night_id: uuid.UUID, status: str) -> list[uuid.UUID]:
    """IDs of the night's jobs in `status`."""
    query = select(Job.id).where(Job.night_id == night_id, Job.status == status)
    return list(session.scalars(query))


def declared_bytes(session: Session, night_id: uuid.UUID) -> int:
    """Bytes declared by every job of the night (for the night quota)."""
    query = (
        select(func.coalesce(func.sum(InputFile.size), 0)).join(Job).where(Job.night_id == night_id)
    )
    return int(session.scalar(query) or 0)
