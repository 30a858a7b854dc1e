"""Both storage backends through the one interface (S3 against moto's server)."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from services.core.storage import (
    MissingObjectError,
    Storage,
    StorageError,
    TransientStorageError,
    sha256_file,
)
from services.core.storage.local import LocalStorage
from services.core.storage.s3 import S3Storage
from tests.services.conftest import BUCKET, free_port


@pytest.fixture(params=["local", "s3"])
def storage(request: pytest.FixtureRequest, tmp_path: Path) -> Storage:
    if request.param == "local":
        return LocalStorage(tmp_path / "store")
    endpoint = request.getfixturevalue("s3_endpoint")
    return S3Storage(BUCKET, endpoint_url=endpoint, access_key_id="t", secret_access_key="t")


@pytest.fixture
def prefix() -> str:
    return f"jobs/{uuid.uuid4()}/"


@pytest.fixture
def blob(tmp_path: Path) -> Iterator[Path]:
    path = tmp_path / "blob.bin"
    path.write_bytes(os.urandom(3 << 20))
    yield path


def test_round_trip(storage: Storage, prefix: str, blob: Path, tmp_path: Path) -> None:
    key = f"{prefix}work/tracking/cam1/00000000-00000180.npz"
    storage.upload_file(blob, key, "application/octet-stream")
    storage.upload_file(blob, f"{prefix}report/a.png", "image/png")
    assert storage.size(key) == blob.stat().st_size
    assert storage.list_keys(prefix) == sorted([key, f"{prefix}report/a.png"])
    assert b"".join(storage.iter_bytes(key)) == blob.read_bytes()
    storage.download_file(key, tmp_path / "copy")
    assert sha256_file(tmp_path / "copy") == sha256_file(blob)

    storage.delete(key)
    storage.delete(key)  # absent: no error
    assert storage.size(key) is None
    assert storage.list_keys(prefix) == [f"{prefix}report/a.png"]
    with pytest.raises(MissingObjectError, match="no object"):
        storage.download_file(key, tmp_path / "missing")
    storage.check()


def test_download_urls(storage: Storage, prefix: str, blob: Path) -> None:
    key = f"{prefix}trajectories.csv"
    storage.upload_file(blob, key, "text/csv")
    url = storage.download_url(key, 60, "trajectories.csv", "attachment")
    if isinstance(storage, LocalStorage):
        assert url is None  # the API streams it behind a signed link
        return
    assert url is not None
    response = httpx.get(url)
    assert response.status_code == 200 and response.content == blob.read_bytes()
    assert response.headers["content-disposition"] == 'attachment; filename="trajectories.csv"'


def test_local_keys_cannot_escape_the_root(tmp_path: Path) -> None:
    storage = LocalStorage(tmp_path / "store")
    for key in ("../outside", "/etc/passwd", "jobs/../../x", "jobs//x", "a\\b"):
        with pytest.raises(StorageError, match="invalid storage key"):
            storage.size(key)


def test_local_partial_upload_is_exclusive_and_ordered(tmp_path: Path) -> None:
    storage = LocalStorage(tmp_path / "store")
    key = "jobs/x/input/cam1/00.mp4"
    with storage.open_append(key, 0) as handle:
        handle.write(b"abc")
        with pytest.raises(StorageError, match="in progress"):
            storage.open_append(key, 3)
    with pytest.raises(StorageError, match="at byte 3, not 5"):
        storage.open_append(key, 5)
    with storage.open_append(key, 2) as handle:  # an unfinished part is dropped
        handle.write(b"cdef")
    assert storage.partial_path(key).read_bytes() == b"abcdef" and storage.size(key) is None
    storage.publish_partial(key)
    assert b"".join(storage.iter_bytes(key)) == b"abcdef"
    assert not storage.partial_path(key).exists()
    assert storage.list_keys("jobs/") == [key]


def test_unreachable_s3_is_transient(tmp_path: Path) -> None:
    storage = S3Storage(
        BUCKET,
        endpoint_url=f"http://127.0.0.1:{free_port()}",
        access_key_id="t",
        secret_access_key="t",
    )
    storage.client.meta.config.retries = {"max_attempts": 1}
    with pytest.raises(TransientStorageError, match="S3 unreachable"):
        storage.size("jobs/x")


def test_missing_bucket_is_permanent(s3_endpoint: str) -> None:
    storage = S3Storage(
        "no-such-bucket", endpoint_url=s3_endpoint, access_key_id="t", secret_access_key="t"
    )
    with pytest.raises(StorageError, match="NoSuchBucket"):
        storage.list_keys("jobs/")
