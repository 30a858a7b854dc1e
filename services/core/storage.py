"""Object storage behind one interface: S3 (boto3) or a local directory.

Keys are ``/``-separated relative paths (``jobs/<job_id>/trajectories.csv``). Large
inputs reach storage without passing through the API's memory: with S3 the browser
uploads parts to presigned URLs (multipart upload); with a local directory the API
appends the streamed request body to a partial file and publishes it when complete.
"""

from __future__ import annotations

import fcntl
import hashlib
import shutil
from abc import ABC, abstractmethod
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, ClassVar, Literal, NoReturn

import boto3
from botocore.config import Config
from botocore.exceptions import BotoCoreError, ClientError
from botocore.exceptions import ConnectionError as BotoConnectionError

from services.core.settings import Settings

UploadMode = Literal["s3-multipart", "stream"]
Disposition = Literal["inline", "attachment"]
READ_CHUNK = 1 << 20
#: S3's multipart limits: at most 10,000 parts of 5 MiB to 5 GiB (the last may be smaller).
MAX_PARTS = 10_000
MAX_PART_BYTES = 5 << 30


class StorageError(Exception):
    """A storage operation failed for a reason that retrying will not fix."""


class MissingObjectError(StorageError):
    """The key does not exist."""


class TransientStorageError(Exception):
    """The storage service was unreachable or overloaded: retrying may succeed."""


@dataclass(frozen=True)
class UploadedPart:
    number: int
    size: int
    etag: str


def part_size_for(size: int, min_part_bytes: int) -> int:
    """Smallest part size, in whole MiB and at least `min_part_bytes`, that fits S3's limits.

    Parameters
    ----------
    size : int
        File size in bytes.
    min_part_bytes : int
        Preferred lower bound (S3 requires ≥ 5 MiB for every part but the last).
    """
    mib = 1 << 20
    needed = max(min_part_bytes, -(-size // MAX_PARTS))
    part = -(-needed // mib) * mib
    if part > MAX_PART_BYTES:
        raise StorageError(f"a {size}-byte file exceeds S3's multipart limit")
    return part


def sha256_file(path: Path) -> str:
    """Hex SHA-256 of a file, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while chunk := handle.read(READ_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


class Storage(ABC):
    """Operations the API and the worker need from an object store."""

    upload_mode: ClassVar[UploadMode]

    @abstractmethod
    def upload_file(self, path: Path, key: str, content_type: str) -> None:
        """Store a local file under `key`, replacing any previous object."""

    @abstractmethod
    def download_file(self, key: str, path: Path) -> None:
        """Write the object at `key` to `path` (streamed)."""

    @abstractmethod
    def iter_bytes(self, key: str) -> Iterator[bytes]:
        """The object's content in chunks (for streamed HTTP responses)."""

    @abstractmethod
    def size(self, key: str) -> int | None:
        """Size in bytes, or None if there is no object at `key`."""

    @abstractmethod
    def list_keys(self, prefix: str) -> list[str]:
        """All keys starting with `prefix`, sorted."""

    @abstractmethod
    def delete(self, key: str) -> None:
        """Remove the object at `key` (no error if it is absent)."""

    @abstractmethod
    def download_url(
        self, key: str, expires_s: int, filename: str, disposition: Disposition
    ) -> str | None:
        """A short-lived URL the browser can GET directly, or None to stream through the API."""

    @abstractmethod
    def check(self) -> None:
        """Raise if the store is unreachable (for readiness probes)."""

    def _unsupported(self) -> NoReturn:
        other = "multipart" if self.upload_mode == "stream" else "streamed"
        raise StorageError(f"{type(self).__name__} takes {self.upload_mode} uploads, not {other}")

    # --- presigned multipart uploads (S3)
    def create_multipart(self, key: str, content_type: str) -> str:
        self._unsupported()

    def presign_parts(
        self, key: str, upload_id: str, numbers: list[int], expires_s: int
    ) -> dict[int, str]:
        self._unsupported()

    def list_parts(self, key: str, upload_id: str) -> list[UploadedPart]:
        self._unsupported()

    def complete_multipart(self, key: str, upload_id: str, parts: list[UploadedPart]) -> None:
        self._unsupported()

    def abort_multipart(self, key: str, upload_id: str) -> None:
        self._unsupported()

    # --- streamed uploads through the API (local directory)
    def received_bytes(self, key: str) -> int:
        """Bytes of an unfinished streamed upload received so far."""
        self._unsupported()

    def open_append(self, key: str, offset: int) -> BinaryIO:
        """The unfinished upload's partial file, opened for appending at `offset`.

        Raises `StorageError` if another request is appending to it.
        """
        self._unsupported()

    def partial_path(self, key: str) -> Path:
        """Local path of an unfinished streamed upload."""
        self._unsupported()

    def publish_partial(self, key: str) -> None:
        """Make a complete streamed upload the object at `key`."""
        self._unsupported()

    def discard_partial(self, key: str) -> None:
        """Forget an unfinished streamed upload."""
        self._unsupported()


class LocalStorage(Storage):
    """Objects as files under a root directory; partial uploads under ``<root>/.partial``."""

    upload_mode = "stream"

    def __init__(self, root: Path) -> None:
        self.root = root.resolve()
        self.root.mkdir(parents=True, exist_ok=True)

    def _path(self, key: str, base: Path | None = None) -> Path:
        parts = key.split("/")
        if any(p in ("", ".", "..") or "\\" in p or "\0" in p for p in parts):
            raise StorageError(f"invalid storage key {key!r}")
        return (base or self.root).joinpath(*parts)

    def partial_path(self, key: str) -> Path:
        return self._path(key, self.root / ".partial")

    def upload_file(self, path: Path, key: str, content_type: str) -> None:
        target = self._path(key)
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.tmp")
        shutil.copyfile(path, tmp)
        tmp.replace(target)  # atomic: readers never see half a file

    def download_file(self, key: str, path: Path) -> None:
        try:
            shutil.copyfile(self._path(key), path)
        except FileNotFoundError:
            raise MissingObjectError(f"no object {key!r} in {self.root}") from None

    def iter_bytes(self, key: str) -> Iterator[bytes]:
        try:
            handle = self._path(key).open("rb")
        except FileNotFoundError:
            raise MissingObjectError(f"no object {key!r} in {self.root}") from None
        with handle:
            while chunk := handle.read(READ_CHUNK):
                yield chunk

    def size(self, key: str) -> int | None:
        path = self._path(key)
        return path.stat().st_size if path.is_file() else None

    def list_keys(self, prefix: str) -> list[str]:
        base = self.root / prefix.rstrip("/") if prefix else self.root
        candidates = [base] if base.is_file() else base.rglob("*")
        keys = (p.relative_to(self.root).as_posix() for p in candidates if p.is_file())
        return sorted(k for k in keys if k.startswith(prefix) and not k.startswith(".partial/"))

    def delete(self, key: str) -> None:
        self._path(key).unlink(missing_ok=True)

    def download_url(
        self, key: str, expires_s: int, filename: str, disposition: Disposition
    ) -> str | None:
        return None

    def check(self) -> None:
        if not self.root.is_dir():
            raise StorageError(f"storage directory {self.root} is missing")

    def received_bytes(self, key: str) -> int:
        partial = self.partial_path(key)
        return partial.stat().st_size if partial.is_file() else 0

    def open_append(self, key: str, offset: int) -> BinaryIO:
        partial = self.partial_path(key)
        partial.parent.mkdir(parents=True, exist_ok=True)
        handle = partial.open("ab")
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            raise StorageError(f"another upload of {key!r} is in progress") from None
        if handle.tell() != offset:
            handle.close()
            raise StorageError(
                f"upload of {key!r} is at byte {self.received_bytes(key)}, not {offset}"
            )
        return handle

    def publish_partial(self, key: str) -> None:
        target = self._path(key)
        target.parent.mkdir(parents=True, exist_ok=True)
        self.partial_path(key).replace(target)

    def discard_partial(self, key: str) -> None:
        self.partial_path(key).unlink(missing_ok=True)


class S3Storage(Storage):
    """An S3 bucket (AWS, MinIO, moto) through boto3.

    Presigned URLs are signed for ``public_endpoint_url`` when it is set: inside docker
    compose the API reaches MinIO as ``http://minio:9000`` but the browser does not.
    """

    upload_mode = "s3-multipart"

    def __init__(
        self,
        bucket: str,
        *,
        endpoint_url: str | None = None,
        public_endpoint_url: str | None = None,
        region: str = "us-east-1",
        access_key_id: str | None = None,
        secret_access_key: str | None = None,
    ) -> None:
        config = Config(
            signature_version="s3v4",
            s3={"addressing_style": "path"},
            retries={"mode": "standard", "max_attempts": 5},
            connect_timeout=10,
            read_timeout=60,
        )
        session = boto3.session.Session(
            aws_access_key_id=access_key_id,
            aws_secret_access_key=secret_access_key,
            region_name=region,
        )
        self.bucket = bucket
        self.client = session.client("s3", endpoint_url=endpoint_url, config=config)
        self.public_client = session.client(
            "s3", endpoint_url=public_endpoint_url or endpoint_url, config=config
        )

    @contextmanager
    def _errors(self, key: str) -> Iterator[None]:
        try:
            yield
        except ClientError as exc:
            error = exc.response.get("Error", {})
            code = str(error.get("Code", ""))
            status = int(exc.response.get("ResponseMetadata", {}).get("HTTPStatusCode", 0))
            if code in ("NoSuchKey", "404", "NotFound"):
                raise MissingObjectError(f"no object {key!r} in bucket {self.bucket}") from exc
            if status >= 500 or code in ("SlowDown", "RequestTimeout", "ServiceUnavailable"):
                raise TransientStorageError(f"S3 {code} on {key!r}: {exc}") from exc
            raise StorageError(f"S3 {code} on {key!r}: {error.get('Message', exc)}") from exc
        except BotoConnectionError as exc:
            raise TransientStorageError(f"S3 unreachable for {key!r}: {exc}") from exc
        except BotoCoreError as exc:
            raise StorageError(f"S3 error on {key!r}: {exc}") from exc

    def upload_file(self, path: Path, key: str, content_type: str) -> None:
        with self._errors(key):
            self.client.upload_file(
                str(path), self.bucket, key, ExtraArgs={"ContentType": content_type}
            )

    def download_file(self, key: str, path: Path) -> None:
        with self._errors(key):
            self.client.download_file(self.bucket, key, str(path))

    def iter_bytes(self, key: str) -> Iterator[bytes]:
        with self._errors(key):
            body = self.client.get_object(Bucket=self.bucket, Key=key)["Body"]
            yield from body.iter_chunks(READ_CHUNK)

    def size(self, key: str) -> int | None:
        try:
            with self._errors(key):
                return int(self.client.head_object(Bucket=self.bucket, Key=key)["ContentLength"])
        except MissingObjectError:
            return None

    def list_keys(self, prefix: str) -> list[str]:
        with self._errors(prefix):
            pages = self.client.get_paginator("list_objects_v2").paginate(
                Bucket=self.bucket, Prefix=prefix
            )
            return sorted(obj["Key"] for page in pages for obj in page.get("Contents", []))

    def delete(self, key: str) -> None:
        with self._errors(key):
            self.client.delete_object(Bucket=self.bucket, Key=key)

    def download_url(
        self, key: str, expires_s: int, filename: str, disposition: Disposition
    ) -> str | None:
        params = {
            "Bucket": self.bucket,
            "Key": key,
            "ResponseContentDisposition": f'{disposition}; filename="{filename}"',
        }
        return str(
            self.public_client.generate_presigned_url(
                "get_object", Params=params, ExpiresIn=expires_s
            )
        )

    def check(self) -> None:
        with self._errors(""):
            self.client.head_bucket(Bucket=self.bucket)

    def create_multipart(self, key: str, content_type: str) -> str:
        with self._errors(key):
            response = self.client.create_multipart_upload(
                Bucket=self.bucket, Key=key, ContentType=content_type
            )
        return str(response["UploadId"])

    def presign_parts(
        self, key: str, upload_id: str, numbers: list[int], expires_s: int
    ) -> dict[int, str]:
        def sign(number: int) -> str:
            params = {
                "Bucket": self.bucket,
                "Key": key,
                "UploadId": upload_id,
                "PartNumber": number,
            }
            return str(
                self.public_client.generate_presigned_url(
                    "upload_part", Params=params, ExpiresIn=expires_s
                )
            )

        return {number: sign(number) for number in numbers}

    def list_parts(self, key: str, upload_id: str) -> list[UploadedPart]:
        with self._errors(key):
            pages = self.client.get_paginator("list_parts").paginate(
                Bucket=self.bucket, Key=key, UploadId=upload_id
            )
            return [
                UploadedPart(int(p["PartNumber"]), int(p["Size"]), str(p["ETag"]))
                for page in pages
                for p in page.get("Parts", [])
            ]

    def complete_multipart(self, key: str, upload_id: str, parts: list[UploadedPart]) -> None:
        with self._errors(key):
            self.client.complete_multipart_upload(
                Bucket=self.bucket,
                Key=key,
                UploadId=upload_id,
                MultipartUpload={
                    "Parts": [{"PartNumber": p.number, "ETag": p.etag} for p in parts]
                },
            )

    def abort_multipart(self, key: str, upload_id: str) -> None:
        with self._errors(key):
            self.client.abort_multipart_upload(Bucket=self.bucket, Key=key, UploadId=upload_id)


def make_storage(settings: Settings) -> Storage:
    """The storage backend the settings select."""
    if settings.storage_backend == "local":
        return LocalStorage(settings.local_storage_dir)
    key_id, secret = settings.s3_access_key_id, settings.s3_secret_access_key
    return S3Storage(
        settings.s3_bucket,
        endpoint_url=settings.s3_endpoint_url,
        public_endpoint_url=settings.s3_public_endpoint_url,
        region=settings.s3_region,
        access_key_id=key_id.get_secret_value() if key_id else None,
        secret_access_key=secret.get_secret_value() if secret else None,
    )
