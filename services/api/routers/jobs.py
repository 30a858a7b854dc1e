"""``/api/v1/jobs``: create, upload, submit, follow, cancel, download."""

from __future__ import annotations

import uuid
from typing import Annotated

from fastapi import APIRouter, Path, Request, status
from fastapi.responses import Response

from services.api import artifacts, jobs, uploads
from services.api.deps import (
    PrincipalDep,
    SendDep,
    SessionDep,
    SessionsDep,
    SettingsDep,
    StorageDep,
    TeamDep,
    job_for,
)
from services.api.schemas import (
    ArtifactOut,
    FileDeclaration,
    FileStatus,
    JobCreate,
    JobOut,
    PartsRequest,
    PartsSigned,
)
from services.core import workflow

router = APIRouter(prefix="/jobs", tags=["jobs"])

Camera = Annotated[int, Path(ge=1, le=2, description="1 or 2")]
Chapter = Annotated[int, Path(ge=0, le=998, description="0-based chapter index")]
CHUNK_UPLOAD = {
    "requestBody": {
        "description": "the file's bytes, or the range named by Content-Range",
        "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}},
    }
}


@router.post("", status_code=status.HTTP_201_CREATED)
def create_job(
    body: JobCreate, team: TeamDep, session: SessionDep, settings: SettingsDep, storage: StorageDep
) -> JobOut:
    """Declare a stereo pair's chapter files; the answer says how to upload each."""
    return jobs.job_out(jobs.create_job(session, settings, team, body), storage)


@router.get("/{job_id}")
def get_job(
    job_id: uuid.UUID, principal: PrincipalDep, session: SessionDep, storage: StorageDep
) -> JobOut:
    """Status, per-stage progress, errors and headline metrics."""
    return jobs.job_out(job_for(session, principal, job_id), storage)


@router.post("/{job_id}/submit")
def submit_job(
    job_id: uuid.UUID,
    principal: PrincipalDep,
    session: SessionDep,
    sessions: SessionsDep,
    storage: StorageDep,
    send: SendDep,
) -> JobOut:
    """Queue a job whose files are all uploaded (its inputs are verified by the probe stage)."""
    job_for(session, principal, job_id)
    workflow.submit(sessions, storage, send, job_id)
    session.expire_all()
    return jobs.job_out(job_for(session, principal, job_id), storage)


@router.post("/{job_id}/cancel")
def cancel_job(
    job_id: uuid.UUID,
    principal: PrincipalDep,
    session: SessionDep,
    sessions: SessionsDep,
    storage: StorageDep,
) -> JobOut:
    """Stop a job; running stages stop at their next progress report."""
    job_for(session, principal, job_id)
    workflow.cancel(sessions, job_id)
    session.expire_all()
    return jobs.job_out(job_for(session, principal, job_id), storage)


@router.get("/{job_id}/files/{camera}/{chapter}")
def get_file(
    job_id: uuid.UUID,
    camera: Camera,
    chapter: Chapter,
    principal: PrincipalDep,
    session: SessionDep,
    storage: StorageDep,
) -> FileStatus:
    """Upload state of one file: bytes received, multipart parts stored (to resume)."""
    job = job_for(session, principal, job_id)
    return uploads.file_status(job, uploads.input_file(job, camera, chapter), storage)


@router.put("/{job_id}/files/{camera}/{chapter}", openapi_extra=CHUNK_UPLOAD)
async def put_file(
    request: Request,
    job_id: uuid.UUID,
    camera: Camera,
    chapter: Chapter,
    principal: PrincipalDep,
    sessions: SessionsDep,
    storage: StorageDep,
) -> FileStatus:
    """Stream a file, or a ``Content-Range`` piece of it, to local storage."""
    return await uploads.stream_upload(
        request, sessions, storage, principal, job_id, camera, chapter
    )


@router.post("/{job_id}/files/{camera}/{chapter}/parts")
def sign_parts(
    job_id: uuid.UUID,
    camera: Camera,
    chapter: Chapter,
    body: PartsRequest,
    principal: PrincipalDep,
    session: SessionDep,
    settings: SettingsDep,
    storage: StorageDep,
) -> PartsSigned:
    """Presigned URLs to PUT parts of a multipart upload straight to S3."""
    job = job_for(session, principal, job_id)
    file = uploads.input_file(job, camera, chapter)
    return uploads.sign_parts(session, settings, storage, job, file, body.part_numbers)


@router.post("/{job_id}/files/{camera}/{chapter}/complete")
def complete_file(
    job_id: uuid.UUID,
    camera: Camera,
    chapter: Chapter,
    principal: PrincipalDep,
    session: SessionDep,
    storage: StorageDep,
) -> FileStatus:
    """Finish a multipart upload once every part is stored."""
    job = job_for(session, principal, job_id)
    return uploads.complete_multipart(
        session, storage, job, uploads.input_file(job, camera, chapter)
    )


@router.post("/{job_id}/files/{camera}/{chapter}/replace")
def replace_file(
    job_id: uuid.UUID,
    camera: Camera,
    chapter: Chapter,
    body: FileDeclaration,
    principal: PrincipalDep,
    session: SessionDep,
    settings: SettingsDep,
    storage: StorageDep,
) -> FileStatus:
    """Declare a different file for a chapter of a job that is not running, to upload anew."""
    job = job_for(session, principal, job_id)
    file = uploads.input_file(job, camera, chapter)
    return uploads.replace_file(session, settings, storage, job, file, body)


@router.get("/{job_id}/artifacts")
def list_artifacts(
    job_id: uuid.UUID,
    principal: PrincipalDep,
    session: SessionDep,
    settings: SettingsDep,
    storage: StorageDep,
) -> list[ArtifactOut]:
    """Every file the job's stages wrote, with a short-lived download link each."""
    return artifacts.list_artifacts(settings, storage, job_for(session, principal, job_id))


@router.get(
    "/{job_id}/artifacts/{name:path}",
    response_class=Response,
    responses={200: {"description": "the file"}, 307: {"description": "presigned URL"}},
)
def get_artifact(
    job_id: uuid.UUID,
    name: str,
    principal: PrincipalDep,
    session: SessionDep,
    settings: SettingsDep,
    storage: StorageDep,
) -> Response:
    """Download an artifact: a redirect to a presigned URL, or the file streamed."""
    artifact = artifacts.find_artifact(job_for(session, principal, job_id), name)
    return artifacts.artifact_response(settings, storage, artifact)
