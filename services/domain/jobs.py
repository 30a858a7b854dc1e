"""Jobs: creation with their declared files, and validated parameters."""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from typing import Any, Protocol

from pydantic import ValidationError
from sqlalchemy.orm import Session

from pipeline.params import ProcessParams
from services.core.models import InputFile, Job, JobStatus, Night, Team, UploadState
from services.core.settings import Settings
from services.core.storage import Storage, part_size_for
from services.domain import access, workflow
from services.domain.errors import Conflict, Invalid
from services.domain.repositories import jobs, nights
from services.domain.workflow import Send, job_key


class DeclaredFile(Protocol):
    """A file declared at job creation (`services.api.schemas.FileDeclaration`)."""

    camera: int
    chapter: int
    filename: str
    size: int
    sha256: str | None


def input_key(job_id: uuid.UUID, camera: int, chapter: int) -> str:
    """Storage key of an input video (the uploaded name is kept only as metadata)."""
    return job_key(job_id, f"input/cam{camera}/{chapter:02d}.mp4")


def merged_params(base: dict[str, Any], overrides: dict[str, Any] | None) -> dict[str, Any]:
    """`base` parameters with `overrides` deep-merged in, validated.

    Raises
    ------
    Invalid
        Naming every invalid parameter and why.
    """
    try:
        params = ProcessParams.model_validate(base).merged(overrides or {})
    except ValidationError as exc:
        messages = "; ".join(
            f"{'.'.join(map(str, e['loc'])) or 'params'}: {e['msg']}" for e in exc.errors()
        )
        raise Invalid(["body", "params"], f"invalid parameters: {messages}") from None
    return params.model_dump(mode="json")


def _check_limits(files: Sequence[DeclaredFile], settings: Settings) -> None:
    for i, declared in enumerate(files):
        if declared.size > settings.max_file_bytes:
            raise Invalid(
                ["body", "files", i, "size"],
                f"{declared.filename}: declared size {declared.size} bytes exceeds the limit "
                f"of {settings.max_file_bytes} bytes per file",
            )
    for camera in (1, 2):
        count = sum(f.camera == camera for f in files)
        if count > settings.max_chapters:
            raise Invalid(
                ["body", "files"],
                f"camera {camera} has {count} chapters; the limit is {settings.max_chapters}",
            )


def _check_quotas(
    session: Session, settings: Settings, night: Night, files: Sequence[DeclaredFile]
) -> None:
    """The team's quotas (settings ``quota_*``; 0 means none) for one more job."""
    total = sum(f.size for f in files)
    if settings.quota_job_bytes and total > settings.quota_job_bytes:
        raise Invalid(
            ["body", "files"],
            f"the files add up to {total} bytes; a job may hold at most "
            f"{settings.quota_job_bytes} bytes (FIREFLY3D_QUOTA_JOB_BYTES)",
        )
    if settings.quota_night_bytes:
        already = nights.declared_bytes(session, night.id) if night.id is not None else 0
        if already + total > settings.quota_night_bytes:
            raise Invalid(
                ["body", "files"],
                f"this night already holds {already} bytes; with these {total} it would "
                f"exceed its quota of {settings.quota_night_bytes} bytes "
                "(FIREFLY3D_QUOTA_NIGHT_BYTES)",
            )


def create_job(
    session: Session,
    settings: Settings,
    team: Team,
    night: uuid.UUID | dict[str, Any],
    files: Sequence[DeclaredFile],
    params: dict[str, Any] | None,
) -> Job:
    """A job in state ``created`` with its files declared (nothing uploaded yet); commits.

    `night` is an existing night's ID, or the fields of a new night, created in the
    same transaction: a job that is refused (a bad parameter, a quota) leaves no
    night behind, and the upload page needs one request before it sends any byte.
    """
    _check_limits(files, settings)
    merged = merged_params(ProcessParams().model_dump(mode="json"), params)
    if isinstance(night, dict):
        target = Night(team_id=team.id, **night)
    else:
        target = access.visible_night(session, access.Principal(team), night)
    _check_quotas(session, settings, target, files)
    job = Job(id=uuid.uuid4(), night=target, params=merged, status=JobStatus.CREATED, summary={})
    job.files = [
        InputFile(
            camera=f.camera,
            chapter=f.chapter,
            filename=f.filename,
            size=f.size,
            sha256=f.sha256,
            storage_key=input_key(job.id, f.camera, f.chapter),
            part_size=part_size_for(f.size, settings.min_part_bytes),
            upload_state=UploadState.PENDING,
        )
        for f in sorted(files, key=lambda f: (f.camera, f.chapter))
    ]
    job.stages = []
    session.add(job)
    session.commit()
    return job


def submit_job(
    session: Session, settings: Settings, storage: Storage, send: Send, job: Job
) -> None:
    """Queue an uploaded job, within the team's quota of active jobs (commits)."""
    limit = settings.quota_active_jobs
    if limit and jobs.active_count(session, job.night.team_id) >= limit:
        raise Conflict(
            f"your team already has {limit} jobs queued or running "
            "(FIREFLY3D_QUOTA_ACTIVE_JOBS): submit this one when one of them has finished"
        )
    workflow.submit(session, storage, send, job.id)
