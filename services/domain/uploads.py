"""Uploads of input videos: presigned S3 multipart, or a stream through the API.

Both paths are resumable. Multipart (`S3Storage`): the browser asks which parts are
stored, signs the missing ones in batches and PUTs them straight to S3, then asks the
API to complete the upload (the API lists the stored parts itself, so the browser
needs no ETags). Stream (`LocalStorage`): the browser PUTs the file in ``part_size``
pieces with ``Content-Range`` headers; the API appends each piece to a partial file,
asks for the current offset after a lost connection, and publishes the file once the
whole of it has arrived with the declared SHA-256. Memory use is one network chunk,
whatever the file size.
"""

from __future__ import annotations

import re
import uuid
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from functools import partial

import anyio.to_thread
from sqlalchemy.orm import Session

from services.core.models import InputFile, Job
from services.core.settings import Settings
from services.core.storage import Storage, StorageError, part_size_for, sha256_file
from services.core.storage.local import LocalStorage
from services.core.storage.s3 import S3Storage
from services.domain import access, states
from services.domain.errors import Conflict, Invalid, NotFound
from services.domain.repositories import jobs

CONTENT_TYPE = "video/mp4"
CONTENT_RANGE = re.compile(r"bytes (\d+)-(\d+)/(\d+)")


@dataclass(frozen=True)
class UploadProgress:
    """Where an upload stands: bytes received and, for multipart, the parts stored."""

    job: Job
    file: InputFile
    received_bytes: int
    uploaded_parts: list[int] = field(default_factory=list)


@dataclass(frozen=True)
class SignedParts:
    part_size: int
    part_count: int
    expires_s: int
    urls: dict[int, str]


def input_file(job: Job, camera: int, chapter: int) -> InputFile:
    for file in job.files:
        if (file.camera, file.chapter) == (camera, chapter):
            return file
    raise NotFound(f"job {job.id} has no file for camera {camera} chapter {chapter}")


def part_count(file: InputFile) -> int:
    return -(-file.size // file.part_size)


def _multipart(storage: Storage) -> S3Storage:
    if not isinstance(storage, S3Storage):
        raise Conflict(f"this server takes {storage.upload_mode} uploads: PUT the file to this URL")
    return storage


def _streamed(storage: Storage) -> LocalStorage:
    if not isinstance(storage, LocalStorage):
        raise Conflict(
            f"this server takes {storage.upload_mode} uploads: use the multipart routes "
            "(…/parts, …/complete)"
        )
    return storage


def _require_uploadable(job: Job, file: InputFile) -> None:
    # The state machine would refuse too; checking first keeps the store untouched.
    if job.status not in states.UPLOADABLE_JOB:
        raise Conflict(f"job {job.id} is {job.status}: its files cannot change now")
    if file.upload_state == "uploaded":
        raise Conflict(
            f"camera {file.camera} chapter {file.chapter} is already uploaded; "
            "POST …/replace to upload a different file"
        )


def progress(job: Job, file: InputFile, storage: Storage) -> UploadProgress:
    """Where the upload of `file` stands."""
    if file.upload_state == "uploaded":
        return UploadProgress(job, file, file.size)
    if isinstance(storage, LocalStorage):
        return UploadProgress(job, file, storage.received_bytes(file.storage_key))
    parts = (
        _multipart(storage).list_parts(file.storage_key, file.upload_id) if file.upload_id else []
    )
    numbers = sorted(p.number for p in parts)
    return UploadProgress(job, file, sum(p.size for p in parts), numbers)


def sign_parts(
    session: Session,
    settings: Settings,
    storage: Storage,
    job: Job,
    file: InputFile,
    numbers: list[int],
) -> SignedParts:
    """Presigned PUT URLs for parts of a multipart upload (started on first request)."""
    s3 = _multipart(storage)
    _require_uploadable(job, file)
    count = part_count(file)
    if max(numbers) > count:
        raise Invalid(
            ["body", "part_numbers"], f"this file has {count} parts of {file.part_size} bytes"
        )
    if file.upload_id is None:
        file.upload_id = s3.create_multipart(file.storage_key, CONTENT_TYPE)
    states.start_upload(job, file)
    session.commit()
    urls = s3.presign_parts(
        file.storage_key, file.upload_id, numbers, settings.upload_url_expires_s
    )
    return SignedParts(file.part_size, count, settings.upload_url_expires_s, urls)


def complete_multipart(
    session: Session, storage: Storage, job: Job, file: InputFile
) -> UploadProgress:
    """Assemble the stored parts into the object after checking their number and sizes."""
    s3 = _multipart(storage)
    _require_uploadable(job, file)
    if file.upload_id is None:
        raise Conflict("no part has been uploaded yet")
    parts = {p.number: p for p in s3.list_parts(file.storage_key, file.upload_id)}
    count = part_count(file)
    missing = [n for n in range(1, count + 1) if n not in parts]
    if missing:
        shown = ", ".join(map(str, missing[:20])) + (" …" if len(missing) > 20 else "")
        raise Conflict(f"{len(missing)} of {count} parts are missing: {shown}")
    for n in range(1, count + 1):
        expected = min(file.part_size, file.size - (n - 1) * file.part_size)
        if parts[n].size != expected:
            raise Invalid(
                ["path", "chapter"],
                f"part {n} has {parts[n].size} bytes, expected {expected}: upload it again",
            )
    s3.complete_multipart(file.storage_key, file.upload_id, [parts[n] for n in range(1, count + 1)])
    stored = s3.size(file.storage_key)
    if stored != file.size:
        raise Invalid(["path", "chapter"], f"stored {stored} bytes, declared {file.size}")
    states.finish_upload(file)
    session.commit()
    return progress(job, file, storage)


def replace_file(
    session: Session,
    settings: Settings,
    storage: Storage,
    job: Job,
    file: InputFile,
    filename: str,
    size: int,
    sha256: str,
) -> UploadProgress:
    """Declare a different file for a chapter (e.g. after a corrupt upload) and reset it."""
    if job.status not in states.UPLOADABLE_JOB:
        raise Conflict(f"job {job.id} is {job.status}: its files cannot change now")
    if size > settings.max_file_bytes:
        raise Invalid(
            ["body", "size"],
            f"declared size {size} bytes exceeds the limit of {settings.max_file_bytes}",
        )
    if isinstance(storage, S3Storage) and file.upload_id is not None:
        storage.abort_multipart(file.storage_key, file.upload_id)
    if isinstance(storage, LocalStorage):
        storage.discard_partial(file.storage_key)
    file.filename, file.size, file.sha256 = filename, size, sha256
    file.part_size = part_size_for(size, settings.min_part_bytes)
    states.restart_upload(file)
    session.commit()
    return progress(job, file, storage)


def _content_range(header: str | None, size: int) -> tuple[int, int | None]:
    """``(first byte, last byte + 1)`` of a request; ``(0, None)`` for a whole file."""
    if header is None:
        return 0, None
    match = CONTENT_RANGE.fullmatch(header.strip())
    if match is None:
        raise Invalid(["header", "content-range"], "expected 'bytes FIRST-LAST/TOTAL'")
    first, last, total = map(int, match.groups())
    if total != size or first > last or last >= size:
        raise Invalid(
            ["header", "content-range"],
            f"range {first}-{last}/{total} does not fit the declared {size} bytes",
        )
    return first, last + 1


async def stream_upload(
    session: Session,
    storage: Storage,
    principal: access.Principal,
    job_id: uuid.UUID,
    camera: int,
    chapter: int,
    content_range: str | None,
    body: AsyncIterator[bytes],
) -> UploadProgress:
    """Append `body` to the file's partial upload; publish it when complete.

    `body` ends early when the client goes away: what arrived of a whole-file PUT is
    kept (the client resumes from `received_bytes`), a short range is dropped.
    """
    local = _streamed(storage)
    file = await anyio.to_thread.run_sync(
        partial(_open_upload, session, principal, job_id, camera, chapter)
    )
    first, end = _content_range(content_range, file.size)
    received = local.received_bytes(file.storage_key)
    if end is None and received:
        local.discard_partial(file.storage_key)  # a whole-file PUT starts over
        received = 0
    if first != received:
        raise Conflict(
            f"upload is at byte {received}; send the range starting there",
            headers={"Upload-Offset": str(received)},
        )
    limit = end if end is not None else file.size
    try:
        handle = local.open_append(file.storage_key, first)
    except StorageError as exc:
        raise Conflict(str(exc)) from None
    with handle:
        written = 0
        async for chunk in body:
            written += len(chunk)
            if first + written > limit:
                handle.truncate(first)
                raise Invalid(["body"], f"body is longer than the {limit - first} bytes announced")
            handle.write(chunk)
        if end is not None and first + written != end:
            handle.truncate(first)
            raise Invalid(
                ["body"], f"body has {written} bytes, Content-Range announced {end - first}"
            )
    return await anyio.to_thread.run_sync(
        partial(_after_append, session, local, job_id, camera, chapter)
    )


def _open_upload(
    session: Session,
    principal: access.Principal,
    job_id: uuid.UUID,
    camera: int,
    chapter: int,
) -> InputFile:
    job = access.visible_job(session, principal, job_id)
    file = input_file(job, camera, chapter)
    _require_uploadable(job, file)
    states.start_upload(job, file)
    session.commit()  # also returns the connection to the pool while bytes arrive
    return file


def _after_append(
    session: Session, storage: LocalStorage, job_id: uuid.UUID, camera: int, chapter: int
) -> UploadProgress:
    job = jobs.lock(session, job_id)  # read afresh: the bytes took their time
    if job is None:
        raise NotFound(f"job {job_id} not found")
    file = input_file(job, camera, chapter)
    if storage.received_bytes(file.storage_key) == file.size:
        actual = sha256_file(storage.partial_path(file.storage_key))
        if actual != file.sha256:
            storage.discard_partial(file.storage_key)
            states.restart_upload(file)
            session.commit()
            raise Invalid(
                ["body"],
                f"{file.filename}: SHA-256 of the received file is {actual}, declared "
                f"{file.sha256}; upload it again",
            )
        storage.publish_partial(file.storage_key)
        states.finish_upload(file)
    session.commit()
    return progress(job, file, storage)
