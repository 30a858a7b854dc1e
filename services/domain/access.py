"""Who is calling, and what they may see: teams see their own nights and jobs only."""

from __future__ import annotations

import uuid
from dataclasses import dataclass

from sqlalchemy.orm import Session

from services.core.models import Job, Night, Team
from services.core.security import hash_token, tokens_equal
from services.core.settings import Settings
from services.domain.errors import Forbidden, NotFound, Unauthenticated
from services.domain.repositories import jobs, nights, teams


@dataclass(frozen=True)
class Principal:
    """The caller: a team, or the admin (who may read every team's jobs)."""

    team: Team | None
    is_admin: bool = False


def authenticate(session: Session, settings: Settings, token: str | None) -> Principal:
    """The principal a bearer token stands for.

    Raises
    ------
    Unauthenticated
        Without a token, or for a token that is neither the admin's nor a team's.
    """
    if token is None:
        raise Unauthenticated("missing bearer token (Authorization: Bearer <token>)")
    admin = settings.admin_token
    if admin is not None and tokens_equal(token, admin.get_secret_value()):
        return Principal(team=None, is_admin=True)
    team = teams.by_token_hash(session, hash_token(token))
    if team is None:
        raise Unauthenticated("invalid token")
    return Principal(team=team)


def require_team(principal: Principal) -> Team:
    if principal.team is None:
        raise Forbidden("this route needs a team token")
    return principal.team


def require_admin(principal: Principal) -> Principal:
    if not principal.is_admin:
        raise Forbidden("this route needs the admin token")
    return principal


def _visible(principal: Principal, night: Night) -> bool:
    return principal.is_admin or (principal.team is not None and night.team_id == principal.team.id)


def visible_night(session: Session, principal: Principal, night_id: uuid.UUID) -> Night:
    """The night if the caller may see it; `NotFound` otherwise (other teams' IDs stay secret)."""
    night = nights.get(session, night_id)
    if night is None or not _visible(principal, night):
        raise NotFound(f"night {night_id} not found")
    return night


def visible_job(session: Session, principal: Principal, job_id: uuid.UUID) -> Job:
    """The job if the caller may see it; `NotFound` otherwise."""
    job = jobs.get(session, job_id)
    if job is None or not _visible(principal, job.night):
        raise NotFound(f"job {job_id} not found")
    return job
