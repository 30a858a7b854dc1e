"""Teams and their tokens: create, list, issue, revoke, rotate (CLI and admin API).

A token is shown once, when issued; only its SHA-256 is stored. A team may hold several
valid tokens, which is what makes rotation painless: issue a new one, hand it out,
then revoke the old one (`rotate` does both at once for a lost or leaked token).
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy.orm import Session

from services.core.models import Team, TeamToken
from services.core.security import hash_token, new_team_token
from services.domain import states
from services.domain.errors import Conflict, Invalid, NotFound
from services.domain.repositories import teams


@dataclass(frozen=True)
class Issued:
    """A new token: `secret` is the bearer token itself, never stored."""

    team: Team
    token: TeamToken
    secret: str


def _expiry(days: float | None) -> datetime | None:
    if days is None:
        return None
    if days <= 0:
        raise Invalid(["body", "expires_in_days"], "a token must expire in the future")
    return states.now() + timedelta(days=days)


def create_team(session: Session, name: str, expires_in_days: float | None = None) -> Issued:
    """A new team with its first token (commits)."""
    name = name.strip()
    if not name or len(name) > 100:
        raise Invalid(["body", "name"], "a team name has 1 to 100 characters")
    if teams.by_name(session, name) is not None:
        raise Conflict(f"team {name!r} already exists")
    team = Team(id=uuid.uuid4(), name=name)
    session.add(team)
    return issue_token(session, team, "initial", expires_in_days)


def issue_token(
    session: Session, team: Team, label: str, expires_in_days: float | None = None
) -> Issued:
    """A further valid token for `team` (commits)."""
    secret = new_team_token()
    token = TeamToken(
        id=uuid.uuid4(),
        team=team,
        token_hash=hash_token(secret),
        label=label.strip()[:100],
        expires_at=_expiry(expires_in_days),
    )
    session.add(token)
    session.commit()
    return Issued(team, token, secret)


def find_team(session: Session, team_id: uuid.UUID) -> Team:
    team = teams.get(session, team_id)
    if team is None:
        raise NotFound(f"team {team_id} not found")
    return team


def list_teams(session: Session) -> list[Team]:
    return teams.listing(session)


def revoke_token(session: Session, token_id: uuid.UUID) -> TeamToken:
    """Revoke a token at once (commits); API processes forget it within ``auth_cache_s``."""
    token = teams.token(session, token_id)
    if token is None:
        raise NotFound(f"token {token_id} not found")
    if token.revoked_at is None:
        token.revoked_at = states.now()
    session.commit()
    return token


def rotate(
    session: Session, team: Team, label: str = "rotated", expires_in_days: float | None = None
) -> Issued:
    """Revoke every valid token of `team` and issue a new one (commits)."""
    when = states.now()
    for token in team.tokens:
        if token.revoked_at is None:
            token.revoked_at = when
    return issue_token(session, team, label, expires_in_days)


def token_state(token: TeamToken) -> str:
    """ "valid", "valid until …", "expired …" or "revoked …" (for listings)."""
    if token.revoked_at is not None:
        return f"revoked {token.revoked_at:%Y-%m-%d %H:%M}"
    if token.expires_at is None:
        return "valid"
    word = "valid until" if token.expires_at > states.now() else "expired"
    return f"{word} {token.expires_at:%Y-%m-%d %H:%M}"
