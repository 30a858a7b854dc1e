"""FastAPI dependencies: settings, database session, storage, broker, and who is calling."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy import select
from sqlalchemy.orm import Session, joinedload, selectinload

from services.core.db import SessionFactory
from services.core.models import Job, Night, Team
from services.core.security import hash_token, tokens_equal
from services.core.settings import Settings
from services.core.storage import Storage
from services.core.workflow import Send


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_sessions(request: Request) -> SessionFactory:
    return request.app.state.sessions


def get_session(sessions: Annotated[SessionFactory, Depends(get_sessions)]) -> Iterator[Session]:
    """One session per request; routes that write commit explicitly."""
    with sessions() as session:
        yield session


def get_storage(request: Request) -> Storage:
    return request.app.state.storage


def get_send(request: Request) -> Send:
    return request.app.state.send


SettingsDep = Annotated[Settings, Depends(get_settings)]
SessionsDep = Annotated[SessionFactory, Depends(get_sessions)]
SessionDep = Annotated[Session, Depends(get_session)]
StorageDep = Annotated[Storage, Depends(get_storage)]
SendDep = Annotated[Send, Depends(get_send)]

bearer = HTTPBearer(auto_error=False, description="a team token, or the admin token")


@dataclass(frozen=True)
class Principal:
    """The caller: a team, or the admin (who may read every team's jobs)."""

    team: Team | None
    is_admin: bool = False


def _unauthorized(detail: str) -> HTTPException:
    return HTTPException(
        status.HTTP_401_UNAUTHORIZED, detail, headers={"WWW-Authenticate": "Bearer"}
    )


def get_principal(
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
    session: SessionDep,
    settings: SettingsDep,
) -> Principal:
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise _unauthorized("missing bearer token (Authorization: Bearer <token>)")
    token = credentials.credentials
    admin = settings.admin_token
    if admin is not None and tokens_equal(token, admin.get_secret_value()):
        return Principal(team=None, is_admin=True)
    team = session.scalars(select(Team).where(Team.token_hash == hash_token(token))).one_or_none()
    if team is None:
        raise _unauthorized("invalid token")
    return Principal(team=team)


PrincipalDep = Annotated[Principal, Depends(get_principal)]


def require_team(principal: PrincipalDep) -> Team:
    if principal.team is None:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "this route needs a team token")
    return principal.team


def require_admin(principal: PrincipalDep) -> Principal:
    if not principal.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "this route needs the admin token")
    return principal


TeamDep = Annotated[Team, Depends(require_team)]
AdminDep = Annotated[Principal, Depends(require_admin)]


def _visible(principal: Principal, night: Night) -> bool:
    return principal.is_admin or (principal.team is not None and night.team_id == principal.team.id)


def night_for(session: Session, principal: Principal, night_id: uuid.UUID) -> Night:
    """The night if the caller may see it; 404 otherwise (other teams' IDs stay secret)."""
    night = session.get(Night, night_id)
    if night is None or not _visible(principal, night):
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"night {night_id} not found")
    return night


def job_for(session: Session, principal: Principal, job_id: uuid.UUID) -> Job:
    """The job if the caller may see it; 404 otherwise."""
    # One query per relation instead of one per row: the job page polls this.
    loads = [joinedload(Job.night), selectinload(Job.files), selectinload(Job.stages)]
    job = session.get(Job, job_id, options=loads)
    if job is None or not _visible(principal, job.night):
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"job {job_id} not found")
    return job


def unprocessable(location: list[str | int], message: str) -> HTTPException:
    """A 422 shaped like FastAPI's own validation errors."""
    detail = [{"loc": location, "msg": message, "type": "value_error"}]
    return HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, detail)
