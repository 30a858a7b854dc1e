"""Uploads of input videos: presigned S3 multipart, or a stream through the API.

Both paths are resumable. Multipart: the browser asks which parts are stored, signs the
missing ones in batches and PUTs them straight to S3, then asks the API to complete the
upload (the API lists the stored parts itself, so the browser needs no ETags). Stream:
the browser PUTs the file in ``part_size`` pieces with ``Content-Range`` headers; the
API appends each piece to a partial file, asks for the current offset after a lost
connection, and publishes the file once the whole of it has arrived with the declared
SHA-256. Memory use is one network chunk, whatever the file size.
"""

from __future__ import annotations

import re
import uuid

from fastapi import HTTPException, Request, status
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

from services.api.deps import Principal, job_for, unprocessable
from services.api.jobs import file_out
from services.api.schemas import FileDeclaration, FileStatus, PartsSigned, PartUrl
from services.core.db import SessionFactory
from services.core.models import InputFile, Job, JobStatus, UploadState
from services.core.settings import Settings
from services.core.storage import (
    Storage,
    StorageError,
    UploadedPart,
    part_size_for,
    sha256_file,
)
from services.core.workflow import now

#: Jobs whose files may be uploaded or replaced (a finished job before an admin re-run).
UPLOADABLE = (JobStatus.CREATED, JobStatus.UPLOADING, JobStatus.FAILED, JobStatus.CANCELLED)
CONTENT_TYPE = "video/mp4"
CONTENT_RANGE = re.compile(r"bytes (\d+)-(\d+)/(\d+)")


def conflict(message: str) -> HTTPException:
    return HTTPException(status.HTTP_409_CONFLICT, message)


def input_file(job: Job, camera: int, chapter: int) -> InputFile:
    for file in job.files:
        if (file.camera, file.chapter) == (camera, chapter):
            return file
    raise HTTPException(
        status.HTTP_404_NOT_FOUND, f"job {job.id} has no file for camera {camera} chapter {chapter}"
    )


def _require_uploadable(job: Job, file: InputFile) -> None:
    if job.status not in UPLOADABLE:
        raise conflict(f"job {job.id} is {job.status}: its files cannot change now")
    if file.upload_state == UploadState.UPLOADED:
        raise conflict(
            f"camera {file.camera} chapter {file.chapter} is already uploaded; "
            "POST …/replace to upload a different file"
        )


def _require_mode(storage: Storage, mode: str, file: InputFile) -> None:
    if storage.upload_mode != mode:
        hint = (
            "PUT the file to this URL"
            if storage.upload_mode == "stream"
            else "use the multipart routes (…/parts, …/complete)"
        )
        raise conflict(f"this server takes {storage.upload_mode} uploads: {hint}")


def _mark_uploading(job: Job, file: InputFile) -> None:
    file.upload_state = UploadState.UPLOADING
    if job.status == JobStatus.CREATED:
        job.status = JobStatus.UPLOADING


def file_status(job: Job, file: InputFile, storage: Storage) -> FileStatus:
    """Where an upload stands: bytes received and, for multipart, parts stored."""
    parts: list[UploadedPart] = []
    if file.upload_state == UploadState.UPLOADED:
        received = file.size
    elif storage.upload_mode == "stream":
        received = storage.received_bytes(file.storage_key)
    else:
        parts = storage.list_parts(file.storage_key, file.upload_id) if file.upload_id else []
        received = sum(p.size for p in parts)
    return FileStatus(
        **file_out(job, file, storage).model_dump(),
        received_bytes=received,
        uploaded_parts=sorted(p.number for p in parts),
    )


def sign_parts(
    session: Session,
    settings: Settings,
    storage: Storage,
    job: Job,
    file: InputFile,
    numbers: list[int],
) -> PartsSigned:
    """Presigned PUT URLs for parts of a multipart upload (started on first request)."""
    _require_mode(storage, "s3-multipart", file)
    _require_uploadable(job, file)
    count = -(-file.size // file.part_size)
    if max(numbers) > count:
        raise unprocessable(
            ["body", "part_numbers"], f"this file has {count} parts of {file.part_size} bytes"
        )
    if file.upload_id is None:
        file.upload_id = storage.create_multipart(file.storage_key, CONTENT_TYPE)
    _mark_uploading(job, file)
    session.commit()
    urls = storage.presign_parts(
        file.storage_key, file.upload_id, numbers, settings.upload_url_expires_s
    )
    return PartsSigned(
        part_size=file.part_size,
        part_count=count,
        expires_s=settings.upload_url_expires_s,
        parts=[PartUrl(number=n, url=u) for n, u in sorted(urls.items())],
    )


def complete_multipart(session: Session, storage: Storage, job: Job, file: InputFile) -> FileStatus:
    """Assemble the stored parts into the object after checking their number and sizes."""
    _require_mode(storage, "s3-multipart", file)
    _require_uploadable(job, file)
    if file.upload_id is None:
        raise conflict("no part has been uploaded yet")
    parts = {p.number: p for p in storage.list_parts(file.storage_key, file.upload_id)}
    count = -(-file.size // file.part_size)
    missing = [n for n in range(1, count + 1) if n not in parts]
    if missing:
        shown = ", ".join(map(str, missing[:20])) + (" …" if len(missing) > 20 else "")
        raise conflict(f"{len(missing)} of {count} parts are missing: {shown}")
    for n in range(1, count + 1):
        expected = min(file.part_size, file.size - (n - 1) * file.part_size)
        if parts[n].size != expected:
            raise unprocessable(
                ["path", "chapter"],
                f"part {n} has {parts[n].size} bytes, expected {expected}: upload it again",
            )
    storage.complete_multipart(
        file.storage_key, file.upload_id, [parts[n] for n in range(1, count + 1)]
    )
    stored = storage.size(file.storage_key)
    if stored != file.size:
        raise unprocessable(["path", "chapter"], f"stored {stored} bytes, declared {file.size}")
    file.upload_state, file.upload_id, file.uploaded_at = UploadState.UPLOADED, None, now()
    session.commit()
    return file_status(job, file, storage)


def replace_file(
    session: Session,
    settings: Settings,
    storage: Storage,
    job: Job,
    file: InputFile,
    body: FileDeclaration,
) -> FileStatus:
    """Declare a different file for a chapter (e.g. after a corrupt upload) and reset it."""
    if job.status not in UPLOADABLE:
        raise conflict(f"job {job.id} is {job.status}: its files cannot change now")
    if (body.camera, body.chapter) != (file.camera, file.chapter):
        raise unprocessable(["body"], "camera and chapter must match the URL")
    if body.size > settings.max_file_bytes:
        raise unprocessable(
            ["body", "size"],
            f"declared size {body.size} bytes exceeds the limit of {settings.max_file_bytes}",
        )
    if file.upload_id is not None:
        storage.abort_multipart(file.storage_key, file.upload_id)
    if storage.upload_mode == "stream":
        storage.discard_partial(file.storage_key)
    file.filename, file.size, file.sha256 = body.filename, body.size, body.sha256
    file.part_size = part_size_for(body.size, settings.min_part_bytes)
    file.upload_state, file.upload_id, file.uploaded_at = UploadState.PENDING, None, None
    session.commit()
    return file_status(job, file, storage)


def _content_range(header: str | None, size: int) -> tuple[int, int | None]:
    """``(first byte, last byte + 1)`` of a request; ``(0, None)`` for a whole file."""
    if header is None:
        return 0, None
    match = CONTENT_RANGE.fullmatch(header.strip())
    if match is None:
        raise unprocessable(["header", "content-range"], "expected 'bytes FIRST-LAST/TOTAL'")
    first, last, total = map(int, match.groups())
    if total != size or first > last or last >= size:
        raise unprocessable(
            ["header", "content-range"],
            f"range {first}-{last}/{total} does not fit the declared {size} bytes",
        )
    return first, last + 1


async def stream_upload(
    request: Request,
    sessions: SessionFactory,
    storage: Storage,
    principal: Principal,
    job_id: uuid.UUID,
    camera: int,
    chapter: int,
) -> FileStatus:
    """Append the request body to the file's partial upload; publish it when complete."""
    file = await run_in_threadpool(
        _open_upload, sessions, storage, principal, job_id, camera, chapter
    )
    first, end = _content_range(request.headers.get("content-range"), file.size)
    received = storage.received_bytes(file.storage_key)
    if end is None and received:
        storage.discard_partial(file.storage_key)  # a whole-file PUT starts over
        received = 0
    if first != received:
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            f"upload is at byte {received}; send the range starting there",
            headers={"Upload-Offset": str(received)},
        )
    limit = end if end is not None else file.size
    try:
        handle = storage.open_append(file.storage_key, first)
    except StorageError as exc:
        raise conflict(str(exc)) from None
    with handle:
        written = 0
        try:
            async for chunk in request.stream():
                written += len(chunk)
                if first + written > limit:
                    handle.truncate(first)
                    raise unprocessable(
                        ["body"], f"body is longer than the {limit - first} bytes announced"
                    )
                handle.write(chunk)
        except ClientDisconnect:
            pass  # keep what arrived: the client resumes from `received_bytes`
        if end is not None and first + written != end:
            handle.truncate(first)
            raise unprocessable(
                ["body"], f"body has {written} bytes, Content-Range announced {end - first}"
            )
    return await run_in_threadpool(_after_append, sessions, storage, job_id, camera, chapter)


def _open_upload(
    sessions: SessionFactory,
    storage: Storage,
    principal: Principal,
    job_id: uuid.UUID,
    camera: int,
    chapter: int,
) -> InputFile:
    with sessions() as session:
        job = job_for(session, principal, job_id)
        file = input_file(job, camera, chapter)
        _require_mode(storage, "stream", file)
        _require_uploadable(job, file)
        _mark_uploading(job, file)
        session.commit()
        return file


def _after_append(
    sessions: SessionFactory, storage: Storage, job_id: uuid.UUID, camera: int, chapter: int
) -> FileStatus:
    with sessions() as session:
        job = session.get_one(Job, job_id)
        file = input_file(job, camera, chapter)
        if storage.received_bytes(file.storage_key) == file.size:
            actual = sha256_file(storage.partial_path(file.storage_key))
            if actual != file.sha256:
                storage.discard_partial(file.storage_key)
                file.upload_state = UploadState.PENDING
                session.commit()
                raise unprocessable(
                    ["body"],
                    f"{file.filename}: SHA-256 of the received file is {actual}, declared "
                    f"{file.sha256}; upload it again",
                )
            storage.publish_partial(file.storage_key)
            file.upload_state, file.uploaded_at = UploadState.UPLOADED, now()
        session.commit()
        return file_status(job, file, storage)
