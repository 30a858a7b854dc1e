"""File checksums built from part checksums, the way S3 builds a multipart object's.

A 30 GB file cannot be hashed by the browser before it is sent (16 minutes in
JavaScript) and should not be re-read by the API after. Each part (``part_size``
bytes, the last one shorter) is hashed while it is sent; the file's checksum is the
SHA-256 of the parts' binary digests, in order: S3's "checksum of checksums" for
SHA-256 multipart uploads. Anyone holding the file and the part size can recompute it.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
from pathlib import Path

READ_CHUNK = 1 << 20


def composite(part_digests: list[str]) -> str:
    """Hex checksum of a file from its parts' hex SHA-256 digests, in part order."""
    outer = hashlib.sha256()
    for digest in part_digests:
        outer.update(bytes.fromhex(digest))
    return outer.hexdigest()


def hex_from_base64(value: str) -> str | None:
    """A base64 SHA-256 digest (S3's ``x-amz-checksum-sha256``) as hex, or None if malformed."""
    try:
        raw = base64.b64decode(value, validate=True)
    except (binascii.Error, ValueError):
        return None
    return raw.hex() if len(raw) == 32 else None


def base64_from_hex(digest: str) -> str:
    return base64.b64encode(bytes.fromhex(digest)).decode()


def file_checksums(path: Path, part_size: int) -> tuple[str, str]:
    """``(SHA-256 of the whole file, composite of its parts)``, in one read."""
    whole, parts = hashlib.sha256(), []
    with path.open("rb") as handle:
        while True:
            part, left = hashlib.sha256(), part_size
            while left and (chunk := handle.read(min(READ_CHUNK, left))):
                part.update(chunk)
                whole.update(chunk)
                left -= len(chunk)
            if left == part_size:
                break
            parts.append(part.hexdigest())
    return whole.hexdigest(), composite(parts)
