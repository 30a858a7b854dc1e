"""Admin use cases: every team's jobs, re-runs of a job or of a night's failed jobs."""

from __future__ import annotations

import uuid
from datetime import datetime
from typing import Any

from sqlalchemy.orm import Session

from services.core.models import Job, JobStatus, Night, Team
from services.core.settings import Settings
from services.core.storage import Storage
from services.domain import workflow
from services.domain.errors import NotFound
from services.domain.jobs import merged_params
from services.domain.repositories import jobs, nights
from services.domain.workflow import Send


def list_jobs(
    session: Session, settings: Settings, status: str | None, limit: int
) -> list[tuple[Job, Night, Team, datetime | None]]:
    """Jobs of every team (in a status, or "stalled"), with when their work stalled."""
    return jobs.listing(session, status, limit, settings.stall_limit_s)


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
