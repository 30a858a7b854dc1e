"""``/api/v1/admin``: failed jobs and re-runs (admin token)."""

from __future__ import annotations

import uuid
from typing import Annotated

from fastapi import APIRouter, Query

from services.api import admin
from services.api.deps import AdminDep, SendDep, SessionDep, SessionsDep, StorageDep
from services.api.schemas import AdminJobOut, RerunOut, RerunRequest
from services.core.models import JobStatus

router = APIRouter(prefix="/admin", tags=["admin"])


@router.get("/jobs")
def list_jobs(
    _: AdminDep,
    session: SessionDep,
    status: Annotated[JobStatus | None, Query(description="only jobs in this state")] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> list[AdminJobOut]:
    """Jobs of every team, most recently changed first."""
    return admin.list_jobs(session, status, limit)


@router.post("/jobs/{job_id}/rerun")
def rerun_job(
    job_id: uuid.UUID,
    body: RerunRequest,
    _: AdminDep,
    session: SessionDep,
    sessions: SessionsDep,
    storage: StorageDep,
    send: SendDep,
) -> RerunOut:
    """Re-run a finished job from a stage (default: its first unfinished one).

    Earlier stages are not run again: their rows and artifacts are reused.
    """
    return admin.rerun_job(session, sessions, storage, send, job_id, body)


@router.post("/nights/{night_id}/rerun-failed")
def rerun_failed(
    night_id: uuid.UUID,
    _: AdminDep,
    session: SessionDep,
    sessions: SessionsDep,
    storage: StorageDep,
    send: SendDep,
) -> list[RerunOut]:
    """Re-run every failed job of a night from its first unfinished stage."""
    return admin.rerun_failed(session, sessions, storage, send, night_id)
