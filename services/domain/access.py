"""Who is calling, and what they may see: teams see their own nights and jobs only."""

from __future__ import annotations

import time
import uuid
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy.orm import Session

from services.core.models import Job, Night, Team
from services.core.security import hash_token, tokens_equal
from services.core.settings import Settings
from services.domain.errors import Forbidden, NotFound, Unauthenticated
from services.domain.repositories import jobs, nights, teams


@dataclass(frozen=True)
class Principal:
    """The caller: a team, or the admin (who may read every team's jobs).

    ``valid_until`` is when the team's token expires (None: never), so that a cached
    principal is not trusted beyond it.
    """

    team: Team | None
    is_admin: bool = False
    valid_until: datetime | None = None


def authenticate(session: Session, settings: Settings, token: str | None) -> Principal:
    """The principal a bearer token stands for.

    Raises
    ------
    Unauthenticated
        Without a token, or for a token that is neither the admin's nor a valid team
        token (unknown, revoked or expired).
    """
    if token is None:
        raise Unauthenticated("missing bearer token (Authorization: Bearer <token>)")
    admin = settings.admin_token
    if admin is not None and tokens_equal(token, admin.get_secret_value()):
        return Principal(team=None, is_admin=True)
    found = teams.valid_token(session, hash_token(token))
    if found is None:
        raise Unauthenticated("invalid, revoked or expired token")
    return Principal(team=found.team, valid_until=found.expires_at)


class PrincipalCache:
    """Recently authenticated tokens of one API process, trusted for ``ttl_s``.

    Status pages poll every few seconds; checking the token in the database each time
    was half of a poll's database work. A revoked token stops working within ``ttl_s``
    (``auth_cache_s``); an expiring one exactly at its expiry. Keyed by token hash.
    """

    def __init__(self, ttl_s: float, max_entries: int = 10_000) -> None:
        self.ttl_s, self.max_entries = ttl_s, max_entries
        self.entries: dict[str, tuple[float, Principal]] = {}

    def get(self, token: str) -> Principal | None:
        key = hash_token(token)
        entry = self.entries.get(key)
        if entry is None:
            return None
        deadline, principal = entry
        if time.time() >= deadline:
            del self.entries[key]
            return None
        return principal

    def put(self, token: str, principal: Principal) -> None:
        if self.ttl_s <= 0 or principal.is_admin:
            return
        if len(self.entries) >= self.max_entries:
            self.entries.clear()  # rare; the next requests simply check again
        deadline = time.time() + self.ttl_s
        if principal.valid_until is not None:
            deadline = min(deadline, principal.valid_until.timestamp())
        self.entries[hash_token(token)] = (deadline, principal)


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


def visible_job_version(session: Session, principal: Principal, job_id: uuid.UUID) -> str:
    """A digest that changes whenever the job's status would, if the caller may see it.

    One cheap statement, so that a poll of an unchanged job costs next to nothing.
    """
    found = jobs.version(session, job_id)
    if found is None or not (
        principal.is_admin or (principal.team and found[0] == principal.team.id)
    ):
        raise NotFound(f"job {job_id} not found")
    return found[1]
