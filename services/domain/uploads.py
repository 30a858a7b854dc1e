"""Uploads of input videos: presigned S3 multipart, or a stream through the API.

Both paths are resumable and checksummed per part (`services.core.checksums`): the
file's checksum is the SHA-256 of its parts' SHA-256 digests, so nobody has to hash a
30 GB file before or after sending it.

Multipart (`S3Storage`): the browser hashes a part, asks for its URL with the digest
(signed into the URL, so S3 refuses a different body; the API records it), PUTs it
straight to S3, several parts at once, then asks the API to complete the upload (the
API lists the stored parts itself, so the browser needs no ETags).

Stream (`LocalStorage`): the browser PUTs the file in ``part_size`` pieces with
``Content-Range`` (or whole); the API hashes each part as it writes it, in a worker
thread (the event loop only moves bytes), checks a part's ``x-amz-checksum-sha256``
if sent, and records the digests of the parts that arrived whole. After a lost
connection the upload continues from the last whole part. A body that ends early is
an error (422, with ``Upload-Offset``), never a 200, and keeps the whole parts.
Memory use is about one megabyte per upload, whatever the file size.

A declared whole-file SHA-256 is optional; when given it is checked too.
"""

from __future__ import annotations

import hashlib
import re
import uuid
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from functools import partial
from typing import BinaryIO

import anyio.to_thread
from sqlalchemy.orm import Session

from services.core.checksums import base64_from_hex, composite, hex_from_base64
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
#: Bytes handed to the writer thread at once (fewer thread hops than network chunks).
WRITE_BATCH = 1 << 20


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


def part_bytes(file: InputFile, number: int) -> int:
    """Size of part `number` (1-based): ``part_size``, the last one shorter."""
    return min(file.part_size, file.size - (number - 1) * file.part_size)


def whole_parts_bytes(file: InputFile) -> int:
    """Bytes of the parts recorded whole, from the first on (where a stream resumes)."""
    n = 0
    while str(n + 1) in file.part_checksums:
        n += 1
    return min(n * file.part_size, file.size)


def _file_checksum(file: InputFile) -> str | None:
    """The checksum of the part checksums, if every part has one."""
    digests = [file.part_checksums.get(str(n)) for n in range(1, part_count(file) + 1)]
    return composite([str(d) for d in digests]) if all(digests) else None


def _locked(session: Session, job: Job) -> Job:
    """The job read afresh under its row lock (until the session commits)."""
    locked = jobs.lock(session, job.id)
    if locked is None:
        raise NotFound(f"job {job.id} not found")
    return locked


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
        return UploadProgress(
            job, file, whole_parts_bytes(file), sorted(map(int, file.part_checksums))
        )
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
    checksums: list[str] | None,
) -> SignedParts:
    """Presigned PUT URLs for parts of a multipart upload (started on first request).

    `checksums` are the parts' base64 SHA-256 digests: signed into the URLs and recorded.
    An upload started with them needs them for every part (S3 checks every part then).
    Pages sign several parts at once: the job's row lock makes one of them start the
    upload and keeps every digest.
    """
    s3 = _multipart(storage)
    job = _locked(session, job)
    file = input_file(job, file.camera, file.chapter)
    _require_uploadable(job, file)
    count = part_count(file)
    if max(numbers) > count:
        raise Invalid(
            ["body", "part_numbers"], f"this file has {count} parts of {file.part_size} bytes"
        )
    digests = [_part_digest(i, c) for i, c in enumerate(checksums or [])]
    if file.upload_id is None:
        file.upload_id = s3.create_multipart(file.storage_key, CONTENT_TYPE, bool(digests))
        file.part_checksums = {}
    elif bool(digests) != bool(file.part_checksums):
        needed = "needs" if file.part_checksums else "was started without"
        raise Invalid(["body", "checksums_sha256"], f"this upload {needed} part checksums")
    signed = dict(zip(map(str, numbers), digests, strict=False))
    file.part_checksums = {**file.part_checksums, **signed}
    states.start_upload(job, file)
    session.commit()
    parts = {n: base64_from_hex(signed[str(n)]) if digests else None for n in numbers}
    urls = s3.presign_parts(file.storage_key, file.upload_id, parts, settings.upload_url_expires_s)
    return SignedParts(file.part_size, count, settings.upload_url_expires_s, urls)


def _part_digest(index: int, checksum: str) -> str:
    digest = hex_from_base64(checksum)
    if digest is None:
        raise Invalid(
            ["body", "checksums_sha256", index], "expected a base64 SHA-256 digest (44 characters)"
        )
    return digest


def complete_multipart(
    session: Session, storage: Storage, job: Job, file: InputFile
) -> UploadProgress:
    """Assemble the stored parts into the object after checking their number and sizes."""
    s3 = _multipart(storage)
    job = _locked(session, job)
    file = input_file(job, file.camera, file.chapter)
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
        if parts[n].size != part_bytes(file, n):
            raise Invalid(
                ["path", "chapter"],
                f"part {n} has {parts[n].size} bytes, expected {part_bytes(file, n)}: "
                "upload it again",
            )
    checksum = _file_checksum(file)
    _require_checksum(file, checksum)
    signed = (
        {n: base64_from_hex(str(file.part_checksums[str(n)])) for n in parts} if checksum else None
    )
    s3.complete_multipart(
        file.storage_key, file.upload_id, [parts[n] for n in range(1, count + 1)], signed
    )
    stored = s3.size(file.storage_key)
    if stored != file.size:
        raise Invalid(["path", "chapter"], f"stored {stored} bytes, declared {file.size}")
    file.checksum = checksum
    states.finish_upload(file)
    session.commit()
    return progress(job, file, storage)


def _require_checksum(file: InputFile, checksum: str | None) -> None:
    """An upload must be verifiable: part checksums, or a declared SHA-256."""
    if checksum is None and file.sha256 is None:
        raise Invalid(
            ["body", "checksums_sha256"],
            f"{file.filename}: no checksum to verify it by: send each part's SHA-256 "
            "(checksums_sha256) or declare the file's sha256",
        )


def replace_file(
    session: Session,
    settings: Settings,
    storage: Storage,
    job: Job,
    file: InputFile,
    filename: str,
    size: int,
    sha256: str | None,
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


class PartWriter:
    """Appends to a partial upload and hashes it part by part (called in a thread).

    With `whole`, it also hashes everything it writes, so that a file sent in one
    request from its first byte is checked against a declared SHA-256 without being
    read again.
    """

    def __init__(
        self, handle: BinaryIO, first: int, part_size: int, size: int, whole: bool
    ) -> None:
        self.handle, self.first, self.offset = handle, first, first
        self.part_size, self.size = part_size, size
        self.hash = hashlib.sha256()
        self.whole = hashlib.sha256() if whole else None
        self.digests: dict[int, str] = {}

    def write(self, data: bytes | bytearray) -> None:
        view = memoryview(data)
        while view:
            part_end = min((self.offset // self.part_size + 1) * self.part_size, self.size)
            piece = view[: part_end - self.offset]
            self.handle.write(piece)
            self.hash.update(piece)
            if self.whole is not None:
                self.whole.update(piece)
            self.offset += len(piece)
            view = view[len(piece) :]
            if self.offset == part_end:
                self.digests[-(-self.offset // self.part_size)] = self.hash.hexdigest()
                self.hash = hashlib.sha256()

    def file_sha256(self) -> str | None:
        """SHA-256 of the whole file, if this writer wrote all of it."""
        complete = self.whole is not None and self.first == 0 and self.offset == self.size
        return self.whole.hexdigest() if complete and self.whole is not None else None

    def whole_end(self) -> int:
        """End of the last part written whole: where the upload continues."""
        return (
            self.size
            if self.offset == self.size
            else self.offset // self.part_size * self.part_size
        )


async def stream_upload(
    session: Session,
    storage: Storage,
    principal: access.Principal,
    job_id: uuid.UUID,
    camera: int,
    chapter: int,
    content_range: str | None,
    part_checksum: str | None,
    body: AsyncIterator[bytes],
) -> UploadProgress:
    """Append `body` to the file's partial upload; publish it when complete.

    The body is a ``Content-Range`` from the first byte not stored yet to a part
    boundary (or the end), or the whole file (which starts the upload over).
    `part_checksum` (base64 SHA-256, ``x-amz-checksum-sha256``) checks a one-part body.
    Whole parts are kept whatever happens next; a body that ends early (the client went
    away) or does not match is answered 422 after they are recorded.
    """
    local = _streamed(storage)
    whole_file = content_range is None
    file = await anyio.to_thread.run_sync(
        partial(_open_upload, session, principal, job_id, camera, chapter, whole_file)
    )
    first, end = _content_range(content_range, file.size)
    received = whole_parts_bytes(file)
    if first != received:
        raise Conflict(
            f"upload is at byte {received}; send the range starting there",
            headers={"Upload-Offset": str(received)},
        )
    limit = file.size if end is None else end
    if limit != file.size and limit % file.part_size:
        raise Invalid(
            ["header", "content-range"],
            f"a range must end at a part boundary (a multiple of {file.part_size}) or the end",
        )
    expected = _expected_part_digest(file, first, limit, part_checksum)
    try:
        handle = await anyio.to_thread.run_sync(local.open_append, file.storage_key, first)
    except StorageError as exc:
        raise Conflict(str(exc)) from None
    writer = PartWriter(handle, first, file.part_size, file.size, file.sha256 is not None)
    try:
        too_long = await _write_body(writer, body, limit)
        kept = first if too_long else writer.whole_end()
        bad_part = None
        if expected is not None and writer.digests.get(expected[0], expected[1]) != expected[1]:
            bad_part, kept = expected[0], first
        await anyio.to_thread.run_sync(handle.truncate, kept)
    finally:
        handle.close()
    digests = {
        n: d for n, d in writer.digests.items() if min(n * file.part_size, file.size) <= kept
    }
    whole = None if kept != file.size else writer.file_sha256()
    upload = await anyio.to_thread.run_sync(
        partial(_after_append, session, local, job_id, camera, chapter, digests, whole)
    )
    if too_long:
        raise Invalid(["body"], f"body is longer than the {limit - first} bytes announced")
    if bad_part is not None:
        raise Invalid(
            ["header", "x-amz-checksum-sha256"],
            f"part {bad_part} does not match its SHA-256 checksum: send it again",
            headers={"Upload-Offset": str(kept)},
        )
    if writer.offset < limit:
        raise Invalid(
            ["body"],
            f"body ended after {writer.offset - first} of {limit - first} bytes; "
            f"{kept} bytes are stored: send the rest from there with Content-Range",
            headers={"Upload-Offset": str(kept)},
        )
    return upload


def _expected_part_digest(
    file: InputFile, first: int, end: int, checksum: str | None
) -> tuple[int, str] | None:
    """``(part number, hex digest)`` a one-part body must have, from its header."""
    if checksum is None:
        return None
    number = first // file.part_size + 1
    digest = hex_from_base64(checksum)
    if first % file.part_size or end - first != part_bytes(file, number) or digest is None:
        raise Invalid(
            ["header", "x-amz-checksum-sha256"],
            "a part checksum is the base64 SHA-256 of a body that is exactly one part",
        )
    return number, digest


async def _write_body(writer: PartWriter, body: AsyncIterator[bytes], limit: int) -> bool:
    """Write `body` through `writer` in batches, in a thread; True if it overran `limit`."""
    batch = bytearray()
    async for chunk in body:
        if writer.offset + len(batch) + len(chunk) > limit:
            return True
        batch += chunk
        if len(batch) >= WRITE_BATCH:
            await anyio.to_thread.run_sync(writer.write, batch)
            batch = bytearray()
    if batch:
        await anyio.to_thread.run_sync(writer.write, batch)
    return False


def _open_upload(
    session: Session,
    principal: access.Principal,
    job_id: uuid.UUID,
    camera: int,
    chapter: int,
    restart: bool,
) -> InputFile:
    job = access.visible_job(session, principal, job_id)
    file = input_file(job, camera, chapter)
    _require_uploadable(job, file)
    states.start_upload(job, file)
    if restart:
        file.part_checksums = {}
    session.commit()  # also returns the connection to the pool while bytes arrive
    return file


def _after_append(
    session: Session,
    storage: LocalStorage,
    job_id: uuid.UUID,
    camera: int,
    chapter: int,
    digests: dict[int, str],
    whole_sha256: str | None,
) -> UploadProgress:
    """Record the parts that arrived whole; publish the file once it is complete.

    `whole_sha256` is the file's SHA-256 if this request carried all of it (else the
    file is read again to check a declared SHA-256).
    """
    job = jobs.lock(session, job_id)  # read afresh: the bytes took their time
    if job is None:
        raise NotFound(f"job {job_id} not found")
    file = input_file(job, camera, chapter)
    file.part_checksums = {**file.part_checksums, **{str(n): d for n, d in digests.items()}}
    if whole_parts_bytes(file) == file.size:
        checksum = _file_checksum(file)
        if file.sha256 is not None:
            actual = whole_sha256 or sha256_file(storage.partial_path(file.storage_key))
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
        file.checksum = checksum
        states.finish_upload(file)
    session.commit()
    return progress(job, file, storage)
