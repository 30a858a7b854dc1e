"""The FastAPI application: REST API under ``/api/v1``, health checks, web pages."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from sqlalchemy.exc import OperationalError

from pipeline import __version__
from services.api.headers import SecurityHeaders
from services.api.ratelimit import FailureLimiter
from services.api.routers import admin, docs, downloads, health, jobs, nights, pages
from services.api.status import StatusCache
from services.api.views import API_PREFIX
from services.core.db import make_engine, make_session_factory
from services.core.settings import Settings, get_settings
from services.core.storage import (
    MissingObjectError,
    StorageError,
    TransientStorageError,
    make_storage,
)
from services.domain.access import PrincipalCache
from services.domain.errors import (
    Conflict,
    DomainError,
    Forbidden,
    Invalid,
    NotFound,
    TooManyRequests,
    Unauthenticated,
    Unavailable,
)
from services.worker.celery_app import make_celery
from services.worker.dispatch import sender

DESCRIPTION = """
Upload stereo 360° recordings of firefly swarms, follow their processing, download
3D flash trajectories.

Authenticate with `Authorization: Bearer <token>`: a team token (`firefly3d admin
create-team NAME`) for a team's own nights and jobs, or the admin token for
`/api/v1/admin`. Errors are JSON `{"detail": ...}`; 422 details say which field is wrong.
"""

#: HTTP status of each kind of error the domain and the storage raise (first match wins).
ERROR_STATUS: tuple[tuple[type[Exception], int], ...] = (
    (NotFound, status.HTTP_404_NOT_FOUND),
    (Conflict, status.HTTP_409_CONFLICT),
    (Invalid, status.HTTP_422_UNPROCESSABLE_CONTENT),
    (Unauthenticated, status.HTTP_401_UNAUTHORIZED),
    (Forbidden, status.HTTP_403_FORBIDDEN),
    (TooManyRequests, status.HTTP_429_TOO_MANY_REQUESTS),
    (Unavailable, status.HTTP_503_SERVICE_UNAVAILABLE),
    (OperationalError, status.HTTP_503_SERVICE_UNAVAILABLE),
    (TransientStorageError, status.HTTP_503_SERVICE_UNAVAILABLE),
    (MissingObjectError, status.HTTP_404_NOT_FOUND),
    (StorageError, status.HTTP_502_BAD_GATEWAY),
)


def _error(_: Request, exc: Exception) -> JSONResponse:
    """The one mapping of domain and storage errors to HTTP responses."""
    code = next(code for kind, code in ERROR_STATUS if isinstance(exc, kind))
    headers = dict(exc.headers) if isinstance(exc, DomainError) else {}
    if isinstance(exc, Unauthenticated):
        headers["WWW-Authenticate"] = "Bearer"
    detail: object = str(exc)
    if isinstance(exc, OperationalError):  # no connection details to the client
        detail = "the database is unavailable; try again"
    if isinstance(exc, Invalid):  # shaped like FastAPI's own validation errors
        detail = [{"loc": exc.location, "msg": exc.message, "type": "value_error"}]
    return JSONResponse({"detail": detail}, status_code=code, headers=headers)


def _invalid_request(_: Request, exc: Exception) -> JSONResponse:
    # FastAPI's default echoes each bad input back, which fails on NaN and can be huge.
    assert isinstance(exc, RequestValidationError)
    detail = [{k: e[k] for k in ("type", "loc", "msg") if k in e} for e in exc.errors()]
    return JSONResponse({"detail": detail}, status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


def create_app(settings: Settings | None = None) -> FastAPI:
    """The API with its own database engine, storage client and broker producer.

    Raises ``ValueError`` without ``FIREFLY3D_SECRET_KEY``: links signed by one API
    process must verify in every other.
    """
    settings = settings or get_settings()
    settings.signing_key()
    # Requests are short: no pre-ping round trip per checkout. A connection that died
    # fails one request (503) and the pool replaces it.
    engine = make_engine(settings.database_url, pre_ping=False)
    celery = make_celery(settings)

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        yield
        engine.dispose()

    app = FastAPI(
        title="firefly3d",
        version=__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
        docs_url=None,  # served offline by services.api.routers.docs
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.sessions = make_session_factory(engine)
    app.state.storage = make_storage(settings)
    app.state.celery = celery
    app.state.send = sender(celery, settings.queue)
    app.state.principals = PrincipalCache(settings.auth_cache_s)
    app.state.auth_limiter = FailureLimiter(
        settings.auth_failures_limit, settings.auth_failures_window_s
    )
    app.state.status_cache = StatusCache()

    for router in (nights.router, jobs.router, downloads.router, admin.router):
        app.include_router(router, prefix=API_PREFIX)
    app.include_router(health.router)
    app.include_router(pages.router)
    app.include_router(docs.router)
    static = Path(__file__).resolve().parent / "static"
    app.mount("/static/apidocs", StaticFiles(packages=[("fastapi_offline", "static")]))
    app.mount("/static", StaticFiles(directory=static), name="static")
    app.add_middleware(SecurityHeaders, settings=settings)

    app.add_exception_handler(RequestValidationError, _invalid_request)
    for kind in (DomainError, StorageError, TransientStorageError, OperationalError):
        app.add_exception_handler(kind, _error)
    return app
