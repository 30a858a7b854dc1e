"""``/api/v1/admin``: every team's jobs and re-runs (admin token)."""

from __future__ import annotations

import uuid
from typing import Annotated

from fastapi import APIRouter, Query

from services.api import views
from services.api.deps import AdminDep, SendDep, SessionDep, StorageDep
from services.api.schemas import AdminJobOut, RerunOut, RerunRequest
from services.core.models import JobStatus
from services.domain import admin

router = APIRouter(prefix="/admin", tags=["admin"])


@router.get("/jobs")
def list_jobs(
    _: AdminDep,
    session: SessionDep,
    status: Annotated[JobStatus | None, Query(description="only jobs in this state")] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> list[AdminJobOut]:
    """Jobs of every team, most recently changed first."""
    rows = admin.list_jobs(session, status, limit)
    return [views.admin_job_out(job, night, team) for job, night, team in rows]


@router.post("/jobs/{job_id}/rerun")
def rerun_job(
    job_id: uuid.UUID,
    body: RerunRequest,
    _: AdminDep,
    session: SessionDep,
    storage: StorageDep,
    send: SendDep,
) -> RerunOut:
    """Re-run a finished job from a stage (default: its first unfinished one).

    Earlier stages are not run again: their rows and artifacts are reused.
    """
    start = admin.rerun_job(session, storage, send, job_id, body.from_stage, body.params)
    return RerunOut(job_id=job_id, from_stage=start, status=JobStatus.QUEUED)


@router.post("/nights/{night_id}/rerun-failed")
def rerun_failed(
    night_id: uuid.UUID, _: AdminDep, session: SessionDep, storage: StorageDep, send: SendDep
) -> list[RerunOut]:
    """Re-run every failed job of a night from its first unfinished stage."""
    return [
        RerunOut(job_id=job_id, from_stage=start, status=JobStatus.QUEUED)
        for job_id, start in admin.rerun_failed(session, storage, send, night_id)
    ]
