"""Jobs: creation with their declared files, and validated parameters."""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from typing import Any, Protocol

from pydantic import ValidationError
from sqlalchemy.orm import Session

from pipeline.params import ProcessParams
from services.core.models import InputFile, Job, JobStatus, Team, UploadState
from services.core.settings import Settings
from services.core.storage import part_size_for
from services.domain import access
from services.domain.errors import Invalid
from services.domain.workflow import job_key


class DeclaredFile(Protocol):
    """A file declared at job creation (`services.api.schemas.FileDeclaration`)."""

    camera: int
    chapter: int
    filename: str
    size: int
    sha256: str


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


def create_job(
    session: Session,
    settings: Settings,
    team: Team,
    night_id: uuid.UUID,
    files: Sequence[DeclaredFile],
    params: dict[str, Any] | None,
) -> Job:
    """A job in state ``created`` with its files declared (nothing uploaded yet); commits."""
    night = access.visible_night(session, access.Principal(team), night_id)
    _check_limits(files, settings)
    merged = merged_params(ProcessParams().model_dump(mode="json"), params)
    job = Job(id=uuid.uuid4(), night=night, params=merged, status=JobStatus.CREATED, summary={})
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
