"""FastAPI dependencies: settings, the request's database session, storage, broker, caller."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import Depends, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from services.core.models import Team
from services.core.settings import Settings
from services.core.storage import Storage
from services.domain import access
from services.domain.access import Principal
from services.domain.errors import Unauthenticated
from services.domain.workflow import Send

# The dependencies that do no I/O are ``async``: FastAPI runs a plain ``def`` dependency
# in its thread pool, and those hops were most of a status poll's overhead.


async def get_settings(request: Request) -> Settings:
    return request.app.state.settings


async def get_session(request: Request) -> AsyncIterator[Session]:
    """The request's one database session (shared by every dependency of the request).

    Opening a session does no I/O; closing one that still holds a connection does
    (a rollback), so that happens in the thread pool.
    """
    session = request.app.state.sessions()
    try:
        yield session
    finally:
        if session.in_transaction():
            await run_in_threadpool(session.close)
        else:
            session.close()


async def get_storage(request: Request) -> Storage:
    return request.app.state.storage


async def get_send(request: Request) -> Send:
    return request.app.state.send


SettingsDep = Annotated[Settings, Depends(get_settings)]
SessionDep = Annotated[Session, Depends(get_session)]
StorageDep = Annotated[Storage, Depends(get_storage)]
SendDep = Annotated[Send, Depends(get_send)]

bearer = HTTPBearer(auto_error=False, description="a team token, or the admin token")


async def get_principal(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
    session: SessionDep,
    settings: SettingsDep,
) -> Principal:
    """The caller, from this process's cache of checked tokens or the database.

    Clients over the failed-authentication limit get 429 before any lookup.
    """
    token = credentials.credentials if credentials is not None else None
    client = request.client.host if request.client else "unknown"
    limiter = request.app.state.auth_limiter
    if token is not None:
        limiter.check(client)
        cached = request.app.state.principals.get(token)
        if cached is not None:
            return cached
    try:
        principal = await run_in_threadpool(access.authenticate, session, settings, token)
    except Unauthenticated:
        if token is not None:
            limiter.failed(client)
        raise
    request.app.state.principals.put(token, principal)
    return principal


PrincipalDep = Annotated[Principal, Depends(get_principal)]


async def require_team(principal: PrincipalDep) -> Team:
    return access.require_team(principal)


async def require_admin(principal: PrincipalDep) -> Principal:
    return access.require_admin(principal)


TeamDep = Annotated[Team, Depends(require_team)]
AdminDep = Annotated[Principal, Depends(require_admin)]
