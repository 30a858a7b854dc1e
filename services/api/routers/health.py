"""``/healthz`` (the process answers) and ``/readyz`` (its dependencies answer)."""

from __future__ import annotations

from collections.abc import Callable

from celery import Celery
from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse
from sqlalchemy import text
from sqlalchemy.orm import Session

from services.api.deps import SessionDep, StorageDep

router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz() -> dict[str, str]:
    """The API process is up."""
    return {"status": "ok"}


def _database(session: Session) -> None:
    session.execute(text("SELECT 1"))


def _broker(celery: Celery) -> None:
    with celery.connection_for_write() as connection:
        connection.ensure_connection(max_retries=1, timeout=3)


def _status(check: Callable[[], None]) -> str:
    try:
        check()
    except Exception as exc:  # any failure means "not ready": say why
        return f"error: {exc}"
    return "ok"


@router.get("/readyz", responses={503: {"description": "a dependency is unreachable"}})
def readyz(request: Request, session: SessionDep, storage: StorageDep) -> JSONResponse:
    """Database, broker and storage all reachable (200), or which is not (503)."""
    checks = {
        "database": _status(lambda: _database(session)),
        "broker": _status(lambda: _broker(request.app.state.celery)),
        "storage": _status(storage.check),
    }
    ready = all(v == "ok" for v in checks.values())
    body = {"status": "ok" if ready else "unavailable", **checks}
    return JSONResponse(body, status_code=200 if ready else 503)
