"""``/api/v1/jobs``: create, upload, submit, follow, cancel, download."""

from __future__ import annotations

import uuid
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Path, Request, status
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import RedirectResponse, Response
from starlette.requests import ClientDisconnect

from services.api import views
from services.api.deps import (
    PrincipalDep,
    SendDep,
    SessionDep,
    SettingsDep,
    StorageDep,
    TeamDep,
)
from services.api.routers.downloads import stream_response
from services.api.schemas import (
    ArtifactOut,
    FileDeclaration,
    FileStatus,
    JobCreate,
    JobOut,
    LinkOut,
    LinkRequest,
    PartsRequest,
    PartsSigned,
)
from services.api.status import Status
from services.domain import access, downloads, jobs, uploads, workflow
from services.domain.errors import Invalid

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
    """Declare a stereo pair's chapter files; the answer says how to upload each.

    Name an existing ``night_id``, or give the ``night`` to create with the job (both
    or neither are stored).
    """
    night = body.night_id if body.night is None else body.night.model_dump()
    assert night is not None  # JobCreate requires one of them
    job = jobs.create_job(session, settings, team, night, body.files, body.params)
    return views.job_out(job, storage)


@router.get(
    "/{job_id}",
    response_model=JobOut,
    responses={304: {"description": "unchanged since the ETag in If-None-Match"}},
)
async def get_job(
    request: Request,
    job_id: uuid.UUID,
    principal: PrincipalDep,
    session: SessionDep,
    storage: StorageDep,
) -> Response:
    """Status, per-stage progress, errors and the run summary so far.

    Answers carry an ``ETag``; with ``If-None-Match`` an unchanged job answers 304.
    """

    def read() -> Status:
        try:
            return request.app.state.status_cache.read(
                session,
                principal,
                job_id,
                request.headers.get("if-none-match"),
                lambda: (
                    views.job_out(access.visible_job(session, principal, job_id), storage)
                    .model_dump_json()
                    .encode()
                ),
            )
        finally:
            session.close()

    status_ = await run_in_threadpool(read)
    headers = {"ETag": status_.etag, "Cache-Control": "no-cache"}
    if status_.body is None:
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers=headers)
    return Response(status_.body, media_type="application/json", headers=headers)


@router.post("/{job_id}/submit")
def submit_job(
    job_id: uuid.UUID,
    principal: PrincipalDep,
    session: SessionDep,
    settings: SettingsDep,
    storage: StorageDep,
    send: SendDep,
) -> JobOut:
    """Queue a job whose files are all uploaded (its inputs are verified by the probe stage)."""
    jobs.submit_job(
        session, settings, storage, send, access.visible_job(session, principal, job_id)
    )
    return views.job_out(access.visible_job(session, principal, job_id), storage)


@router.post("/{job_id}/cancel")
def cancel_job(
    job_id: uuid.UUID, principal: PrincipalDep, session: SessionDep, storage: StorageDep
) -> JobOut:
    """Stop a job; running stages stop at their next progress report."""
    access.visible_job(session, principal, job_id)
    workflow.cancel(session, job_id)
    return views.job_out(access.visible_job(session, principal, job_id), storage)


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
    job = access.visible_job(session, principal, job_id)
    file = uploads.input_file(job, camera, chapter)
    return views.file_status(uploads.progress(job, file, storage), storage)


async def _body(request: Request) -> AsyncIterator[bytes]:
    """The request body; it ends where the client went away."""
    try:
        async for chunk in request.stream():
            yield chunk
    except ClientDisconnect:
        return


@router.put("/{job_id}/files/{camera}/{chapter}", openapi_extra=CHUNK_UPLOAD)
async def put_file(
    request: Request,
    job_id: uuid.UUID,
    camera: Camera,
    chapter: Chapter,
    principal: PrincipalDep,
    session: SessionDep,
    storage: StorageDep,
) -> FileStatus:
    """Stream a file, or a ``Content-Range`` piece of it, to local storage.

    Pieces start where the upload stands (``received_bytes``) and end at a part
    boundary; ``x-amz-checksum-sha256`` (base64 SHA-256) checks a one-part piece. A body
    shorter than announced is 422 with ``Upload-Offset``: the whole parts are kept.
    """
    upload = await uploads.stream_upload(
        session,
        storage,
        principal,
        job_id,
        camera,
        chapter,
        request.headers.get("content-range"),
        request.headers.get("x-amz-checksum-sha256"),
        _body(request),
    )
    return views.file_status(upload, storage)


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
    job = access.visible_job(session, principal, job_id)
    file = uploads.input_file(job, camera, chapter)
    signed = uploads.sign_parts(
        session, settings, storage, job, file, body.part_numbers, body.checksums_sha256
    )
    return views.parts_signed(signed)


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
    job = access.visible_job(session, principal, job_id)
    file = uploads.input_file(job, camera, chapter)
    return views.file_status(uploads.complete_multipart(session, storage, job, file), storage)


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
    job = access.visible_job(session, principal, job_id)
    file = uploads.input_file(job, camera, chapter)
    if (body.camera, body.chapter) != (file.camera, file.chapter):
        raise Invalid(["body"], "camera and chapter must match the URL")
    upload = uploads.replace_file(
        session, settings, storage, job, file, body.filename, body.size, body.sha256
    )
    return views.file_status(upload, storage)


@router.get("/{job_id}/artifacts")
def list_artifacts(
    job_id: uuid.UUID,
    principal: PrincipalDep,
    session: SessionDep,
    settings: SettingsDep,
    storage: StorageDep,
) -> list[ArtifactOut]:
    """Every file the job's stages wrote, with a short-lived download link each."""
    job = access.visible_job(session, principal, job_id)
    return views.artifacts_out(settings, storage, job)


@router.post("/{job_id}/links")
def make_link(
    job_id: uuid.UUID,
    body: LinkRequest,
    principal: PrincipalDep,
    session: SessionDep,
    settings: SettingsDep,
    storage: StorageDep,
) -> LinkOut:
    """A fresh download link for one artifact, or for a zip of all the job's results.

    Pages ask when the user clicks, so a page left open never offers an expired link.
    """
    job = access.visible_job(session, principal, job_id)
    url = downloads.link(settings, storage, job, body.name, views.DOWNLOADS)
    return LinkOut(url=url, expires_s=settings.download_url_expires_s)


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
    artifact = downloads.find_artifact(access.visible_job(session, principal, job_id), name)
    target = downloads.artifact_download(settings, storage, artifact)
    if isinstance(target, str):
        return RedirectResponse(target, status.HTTP_307_TEMPORARY_REDIRECT)
    return stream_response(target)
