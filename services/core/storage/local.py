"""Objects as files under a directory; uploads streamed through the API."""

from __future__ import annotations

import fcntl
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO, Literal

from services.core.storage import READ_CHUNK, Disposition, MissingObjectError, StorageError


class LocalStorage:
    """Objects as files under a root directory; partial uploads under ``<root>/.partial``."""

    upload_mode: Literal["stream"] = "stream"

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

    def read_bytes(self, key: str) -> bytes:
        try:
            return self._path(key).read_bytes()
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

    def open_append(self, key: str, offset: int) -> BinaryIO:
        """The partial upload, locked, positioned to append at `offset`.

        Bytes beyond `offset` (the unfinished part of an interrupted request) are
        dropped: the caller knows which parts arrived whole.
        """
        partial = self.partial_path(key)
        partial.parent.mkdir(parents=True, exist_ok=True)
        handle = partial.open("ab")
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            raise StorageError(f"another upload of {key!r} is in progress") from None
        size = os.fstat(handle.fileno()).st_size
        if size < offset:
            handle.close()
            raise StorageError(f"upload of {key!r} is at byte {size}, not {offset}")
        handle.truncate(offset)
        return handle

    def publish_partial(self, key: str) -> None:
        target = self._path(key)
        target.parent.mkdir(parents=True, exist_ok=True)
        self.partial_path(key).replace(target)

    def discard_partial(self, key: str) -> None:
        self.partial_path(key).unlink(missing_ok=True)
