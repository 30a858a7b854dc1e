"""Queries on teams."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from services.core.models import Team


def by_token_hash(session: Session, token_hash: str) -> Team | None:
    return session.scalars(select(Team).where(Team.token_hash == token_hash)).one_or_none()


def by_name(session: Session, name: str) -> Team | None:
    return session.scalars(select(Team).where(Team.name == name)).one_or_none()
