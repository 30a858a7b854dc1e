"""A zip archive streamed as it is written: no member, and no archive, held in memory.

`zip_stream` takes members as ``(name, content)`` pairs, where content is bytes or an
iterable of byte chunks (read only when the member's turn comes), so adding a member
generated on the fly (e.g. a ``datapackage.json``) is one more pair in the list.
zipfile writes to a non-seekable sink: each member gets a data descriptor after its
data and ZIP64 sizes, so members larger than 4 GiB are fine.
"""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterable, Iterator
from datetime import datetime

ZipContent = bytes | Iterable[bytes]
ZipMember = tuple[str, ZipContent]


class _Sink(io.RawIOBase):
    """Collects what zipfile writes until the generator hands it on."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []

    def writable(self) -> bool:
        return True

    def write(self, data: bytes) -> int:  # type: ignore[override]
        self.chunks.append(bytes(data))
        return len(data)

    def take(self) -> bytes:
        data = b"".join(self.chunks)
        self.chunks.clear()
        return data


def zip_stream(members: Iterable[ZipMember], when: datetime | None = None) -> Iterator[bytes]:
    """The archive of `members`, chunk by chunk (compressed; one timestamp for all)."""
    stamp = (when or datetime(2000, 1, 1)).timetuple()[:6]
    sink = _Sink()
    with zipfile.ZipFile(sink, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, content in members:
            info = zipfile.ZipInfo(name, date_time=stamp)
            info.compress_type = zipfile.ZIP_DEFLATED
            with archive.open(info, "w", force_zip64=True) as entry:
                for chunk in [content] if isinstance(content, bytes) else content:
                    entry.write(chunk)
                    if sink.chunks:
                        yield sink.take()
            yield sink.take()
    yield sink.take()
