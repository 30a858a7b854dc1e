"""FastAPI dependencies: settings, the request's database session, storage, broker, caller."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from services.core.models import Team
from services.core.settings import Settings
from services.core.storage import Storage
from services.domain import access
from services.domain.access import Principal
from services.domain.workflow import Send


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_session(request: Request) -> Iterator[Session]:
    """The request's one database session (shared by every dependency of the request)."""
    with request.app.state.sessions() as session:
        yield session


def get_storage(request: Request) -> Storage:
    return request.app.state.storage


def get_send(request: Request) -> Send:
    return request.app.state.send


SettingsDep = Annotated[Settings, Depends(get_settings)]
SessionDep = Annotated[Session, Depends(get_session)]
StorageDep = Annotated[Storage, Depends(get_storage)]
SendDep = Annotated[Send, Depends(get_send)]

bearer = HTTPBearer(auto_error=False, description="a team token, or the admin token")


def get_principal(
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
    session: SessionDep,
    settings: SettingsDep,
) -> Principal:
    token = credentials.credentials if credentials is not None else None
    return access.authenticate(session, settings, token)


PrincipalDep = Annotated[Principal, Depends(get_principal)]


def require_team(principal: PrincipalDep) -> Team:
    return access.require_team(principal)


def require_admin(principal: PrincipalDep) -> Principal:
    return access.require_admin(principal)


TeamDep = Annotated[Team, Depends(require_team)]
AdminDep = Annotated[Principal, Depends(require_admin)]
