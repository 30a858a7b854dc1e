"""Admin views and re-runs."""

from __future__ import annotations

import uuid

from fastapi import HTTPException, status
from sqlalchemy import select
from sqlalchemy.orm import Session

from services.api.jobs import merged_params
from services.api.schemas import AdminJobOut, RerunOut, RerunRequest
from services.core.db import SessionFactory
from services.core.models import Job, JobStatus, Night, Team
from services.core.storage import Storage
from services.core.workflow import Send, rerun


def list_jobs(session: Session, job_status: JobStatus | None, limit: int) -> list[AdminJobOut]:
    query = select(Job, Night, Team).join(Job.night).join(Night.team)
    if job_status is not None:
        query = query.where(Job.status == job_status)
    rows = session.execute(query.order_by(Job.updated_at.desc()).limit(limit))
    return [
        AdminJobOut(
            id=job.id,
            team=team.name,
            night_id=night.id,
            site=night.site,
            date=night.date,
            status=job.status,
            error=job.error,
            updated_at=job.updated_at,
        )
        for job, night, team in rows
    ]


def rerun_job(
    session: Session,
    sessions: SessionFactory,
    storage: Storage,
    send: Send,
    job_id: uuid.UUID,
    body: RerunRequest,
) -> RerunOut:
    job = session.get(Job, job_id)
    if job is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"job {job_id} not found")
    params = merged_params(job.params, body.params) if body.params is not None else None
    session.rollback()  # release the row: the re-run locks it
    start = rerun(sessions, storage, send, job_id, body.from_stage, params)
    return RerunOut(job_id=job_id, from_stage=start, status=JobStatus.QUEUED)


def rerun_failed(
    session: Session, sessions: SessionFactory, storage: Storage, send: Send, night_id: uuid.UUID
) -> list[RerunOut]:
    if session.get(Night, night_id) is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"night {night_id} not found")
    failed = list(
        session.scalars(
            select(Job.id).where(Job.night_id == night_id, Job.status == JobStatus.FAILED)
        )
    )
    session.rollback()
    return [
        rerun_job(session, sessions, storage, send, job_id, RerunRequest()) for job_id in failed
    ]
