"""Admin use cases: every team's jobs, re-runs of a job or of a night's failed jobs."""

from __future__ import annotations

import uuid
from typing import Any

from sqlalchemy.orm import Session

from services.core.models import Job, JobStatus, Night, Team
from services.core.storage import Storage
from services.domain import workflow
from services.domain.errors import NotFound
from services.domain.jobs import merged_params
from services.domain.repositories import jobs, nights
from services.domain.workflow import Send


def list_jobs(
    session: Session, status: JobStatus | None, limit: int
) -> list[tuple[Job, Night, Team]]:
    return jobs.listing(session, status, limit)


def rerun_job(
    session: Session,
    storage: Storage,
    send: Send,
    job_id: uuid.UUID,
    from_stage: str | None,
    overrides: dict[str, Any] | None,
) -> str:
    """Re-run a finished job from a stage, with parameter overrides; the stage it restarts at."""
    job = jobs.get(session, job_id)
    if job is None:
        raise NotFound(f"job {job_id} not found")
    params = merged_params(job.params, overrides) if overrides is not None else None
    return workflow.rerun(session, storage, send, job_id, from_stage, params)


def rerun_failed(
    session: Session, storage: Storage, send: Send, night_id: uuid.UUID
) -> list[tuple[uuid.UUID, str]]:
    """Re-run every failed job of a night from its first unfinished stage."""
    if nights.get(session, night_id) is None:
        raise NotFound(f"night {night_id} not found")
    failed = nights.job_ids(session, night_id, JobStatus.FAILED)
    return [(job_id, rerun_job(session, storage, send, job_id, None, None)) for job_id in failed]
