"""Fetching a job's files from storage into a task's working directory.

Input videos are verified (size, the checksum of their part checksums recorded at
upload, and the whole file's SHA-256 if the team declared one) as they are downloaded,
and kept in a per-machine cache (per stored object): the chunks of one
camera read the same chapter files, and a worker machine should download each once.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path

from services.core.checksums import file_checksums
from services.core.storage import Storage
from services.domain.workflow import job_key


class InputError(Exception):
    """An uploaded file is not what the team declared."""


@dataclass(frozen=True)
class InputRef:
    """One uploaded chapter file, as declared at job creation."""

    camera: int
    chapter: int
    filename: str
    storage_key: str
    size: int
    sha256: str | None
    part_size: int
    checksum: str | None

    def label(self) -> str:
        return f"camera {self.camera} chapter {self.chapter} ({self.filename})"


def _check_size(path: Path, ref: InputRef) -> None:
    size = path.stat().st_size
    if size != ref.size:
        raise InputError(f"{ref.label()}: stored file has {size} bytes, declared {ref.size}")


def verify(path: Path, ref: InputRef) -> None:
    """Raise `InputError` unless the file at `path` has the size and checksums recorded."""
    _check_size(path, ref)
    whole, parts = file_checksums(path, ref.part_size)
    advice = "the upload was corrupted or the wrong file was sent: replace it and re-run"
    if ref.sha256 is not None and whole != ref.sha256:
        raise InputError(
            f"{ref.label()}: SHA-256 of the uploaded file is {whole}, declared {ref.sha256}; "
            + advice
        )
    if ref.checksum is not None and parts != ref.checksum:
        raise InputError(
            f"{ref.label()}: checksum of the part checksums is {parts}, recorded at upload "
            f"{ref.checksum}; " + advice
        )


class InputCache:
    """Verified input videos on local disk, bounded in total size.

    The cache and the working directories share a filesystem, so a task hard-links its
    inputs: evicting a file another task is reading only drops the cache's name for it.
    """

    def __init__(self, root: Path, max_bytes: int) -> None:
        self.root = root
        self.max_bytes = max_bytes
        root.mkdir(parents=True, exist_ok=True)

    def path_for(self, ref: InputRef) -> Path:
        """Cache entry of one stored object with its declared checksum.

        Keyed by object as well as checksum: a cache hit must not hide that the stored
        object itself is corrupt, which a worker without the entry would find.
        """
        name = f"{ref.storage_key}\n{ref.sha256}\n{ref.checksum}"
        return self.root / hashlib.sha256(name.encode()).hexdigest()

    def fetch(self, storage: Storage, ref: InputRef, dest: Path) -> Path:
        """Place the verified file at `dest` (downloading it unless cached)."""
        dest.parent.mkdir(parents=True, exist_ok=True)
        if self.max_bytes == 0:
            storage.download_file(ref.storage_key, dest)
            verify(dest, ref)
            return dest
        cached = self.path_for(ref)
        if cached.exists():
            _check_size(cached, ref)  # the content matches the checksum: verified on entry
            os.utime(cached)  # most recently used
        else:
            partial = self.root / f".{cached.name}.{uuid.uuid4().hex}.part"
            try:
                storage.download_file(ref.storage_key, partial)
                verify(partial, ref)
                partial.replace(cached)
            finally:
                partial.unlink(missing_ok=True)
        _link_or_copy(cached, dest)
        self._evict(keep=cached)
        return dest

    def _evict(self, keep: Path) -> None:
        files = sorted(
            (p for p in self.root.iterdir() if p.is_file() and not p.name.startswith(".")),
            key=lambda p: p.stat().st_mtime,
        )
        total = sum(p.stat().st_size for p in files)
        for path in files:
            if total <= self.max_bytes:
                break
            if path != keep:
                total -= path.stat().st_size
                path.unlink(missing_ok=True)


def _link_or_copy(source: Path, dest: Path) -> None:
    dest.unlink(missing_ok=True)
    try:
        os.link(source, dest)
    except OSError:  # another filesystem
        shutil.copyfile(source, dest)


def fetch_artifact(storage: Storage, job_id: str, name: str, workdir: Path) -> Path:
    """Download the job's artifact `name` to ``workdir / name``."""
    path = workdir / name
    path.parent.mkdir(parents=True, exist_ok=True)
    storage.download_file(job_key(job_id, name), path)
    return path
