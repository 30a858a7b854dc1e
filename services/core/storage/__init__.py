"""Object storage behind one protocol: S3 (boto3) or a local directory.

Keys are ``/``-separated relative paths (``jobs/<job_id>/trajectories.csv``). Large
inputs reach storage without passing through the API's memory: with S3 the browser
uploads parts to presigned URLs (`S3Storage`'s multipart methods); with a local
directory the API appends the streamed request body to a partial file and publishes it
when complete (`LocalStorage`'s stream methods). Both implement `Storage`, the
operations the API and the workers share; each adds the upload methods of its kind.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

from services.core.settings import Settings

if TYPE_CHECKING:
    from services.core.storage.local import LocalStorage
    from services.core.storage.s3 import S3Storage

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


class Storage(Protocol):
    """Operations the API and the worker need from an object store."""

    @property
    def upload_mode(self) -> UploadMode:
        """How clients upload input files to this store."""
        ...

    def upload_file(self, path: Path, key: str, content_type: str) -> None:
        """Store a local file under `key`, replacing any previous object."""
        ...

    def download_file(self, key: str, path: Path) -> None:
        """Write the object at `key` to `path` (streamed)."""
        ...

    def read_bytes(self, key: str) -> bytes:
        """The whole content of a small object."""
        ...

    def iter_bytes(self, key: str) -> Iterator[bytes]:
        """The object's content in chunks (for streamed HTTP responses)."""
        ...

    def size(self, key: str) -> int | None:
        """Size in bytes, or None if there is no object at `key`."""
        ...

    def list_keys(self, prefix: str) -> list[str]:
        """All keys starting with `prefix`, sorted."""
        ...

    def delete(self, key: str) -> None:
        """Remove the object at `key` (no error if it is absent)."""
        ...

    def download_url(
        self, key: str, expires_s: int, filename: str, disposition: Disposition
    ) -> str | None:
        """A short-lived URL the browser can GET directly, or None to stream through the API."""
        ...

    def check(self) -> None:
        """Raise if the store is unreachable (for readiness probes)."""
        ...


def make_storage(settings: Settings) -> LocalStorage | S3Storage:
    """The storage backend the settings select."""
    from services.core.storage.local import LocalStorage
    from services.core.storage.s3 import S3Storage

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
