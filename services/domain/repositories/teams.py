"""Queries on teams and their tokens."""

from __future__ import annotations

import uuid

from sqlalchemy import func, or_, select
from sqlalchemy.orm import Session, joinedload

from services.core.models import Team, TeamToken


def valid_token(session: Session, token_hash: str) -> TeamToken | None:
    """The token with this hash, with its team, unless revoked or expired."""
    query = (
        select(TeamToken)
        .options(joinedload(TeamToken.team))
        .where(
            TeamToken.token_hash == token_hash,
            TeamToken.revoked_at.is_(None),
            or_(TeamToken.expires_at.is_(None), TeamToken.expires_at > func.now()),
        )
    )
    return session.scalars(query).one_or_none()


def by_name(session: Session, name: str) -> Team | None:
    return session.scalars(select(Team).where(Team.name == name)).one_or_none()


def get(session: Session, team_id: uuid.UUID) -> Team | None:
    return session.get(Team, team_id)


def listing(session: Session) -> list[Team]:
    """Every team with its tokens, by name."""
    query = select(Team).options(joinedload(Team.tokens)).order_by(Team.name)
    return list(session.scalars(query).unique())


def token(session: Session, token_id: uuid.UUID) -> TeamToken | None:
    return session.get(TeamToken, token_id, with_for_update=True)
