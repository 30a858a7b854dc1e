"""Small test videos made on the fly with PyAV (shared by the pipeline tests).

Pictures are given as uint8 luminance ``(H, W)`` (neutral chroma) or RGB ``(H, W, 3)``
arrays; RGB is converted to YUV 4:2:0 here with an explicit matrix and range, and the
stream is tagged with them, so a decoder that honours the tags gets the colours back.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from fractions import Fraction
from pathlib import Path
from typing import Literal

import av
import numpy as np
from numpy.typing import NDArray

Codec = Literal["h264", "hevc"]

_ENCODERS = {"h264": "libx264", "hevc": "libx265"}
_KR_KB = {"bt601": (0.299, 0.114), "bt709": (0.2126, 0.0722)}
_AVCOL_SPC = {"bt601": 6, "bt709": 1}

#: Bits of the frame index drawn by `index_picture` (frames 0 .. 2**16 - 1).
INDEX_BITS = 16


def write_video(
    path: str | Path,
    pictures: Iterable[NDArray[np.uint8]],
    *,
    fps: float = 30.0,
    codec: Codec = "h264",
    crf: int = 12,
    gop: int = 30,
    matrix: Literal["bt601", "bt709"] = "bt601",
    full_range: bool = False,
    faststart: bool = False,
    tag_colour: bool = True,
    pix_fmt: str = "yuv420p",
) -> Path:
    """Encode pictures to an MP4 file and return its path.

    ``crf`` sets the quality (0 lossless .. 51); ``gop`` the keyframe interval (x265
    uses open GOPs, x264 closed ones, as in their defaults). ``faststart`` puts the
    sample table before the media data (what a truncated upload keeps). ``pix_fmt``
    is the coded format (e.g. ``yuv420p10le`` for 10-bit HEVC).
    """
    path = Path(path)
    rate = _rate(fps)
    options = {"movflags": "faststart"} if faststart else {}
    with av.open(str(path), "w", options=options) as container:
        stream: av.VideoStream | None = None
        for picture in pictures:
            if stream is None:
                height, width = picture.shape[:2]
                stream = _add_stream(container, codec, rate, width, height, crf, gop)
                stream.pix_fmt = pix_fmt
                if tag_colour:
                    stream.codec_context.colorspace = _AVCOL_SPC[matrix]
                    stream.codec_context.color_range = 2 if full_range else 1
            yuv = to_yuv420(picture, matrix, full_range)
            frame = av.VideoFrame.from_ndarray(yuv, format="yuv420p")
            container.mux(stream.encode(frame))
        if stream is not None:
            container.mux(stream.encode(None))
    return path


def write_empty_video(path: str | Path, width: int = 640, height: int = 320) -> Path:
    """An MP4 whose video track holds no frames.

    FFmpeg does not mux a track without samples, so a one-frame file is written and
    the entry counts of its sample tables (stts, stsc, stsz, stco) are set to zero.
    """
    path = write_video(path, [np.zeros((height, width), np.uint8)])
    data = bytearray(path.read_bytes())
    # Offset of the entry count after the box type: version/flags, then (stsz) sample size.
    for box, offset in ((b"stts", 4), (b"stsc", 4), (b"stsz", 8), (b"stco", 4)):
        at = data.find(box)
        struct.pack_into(">I", data, at + 4 + offset, 0)
    path.write_bytes(bytes(data))
    return path


def write_chapters(
    directory: str | Path,
    stem: str,
    pictures: Sequence[NDArray[np.uint8]],
    lengths: Sequence[int],
    **options: object,
) -> list[Path]:
    """Split `pictures` into chapter files ``<stem>_00.mp4``, ``<stem>_01.mp4``…"""
    if sum(lengths) != len(pictures):
        raise ValueError(f"chapter lengths {list(lengths)} do not add up to {len(pictures)}")
    paths = []
    first = 0
    for i, n in enumerate(lengths):
        path = Path(directory) / f"{stem}_{i:02d}.mp4"
        paths.append(write_video(path, pictures[first : first + n], **options))  # type: ignore[arg-type]
        first += n
    return paths


def _rate(fps: float) -> Fraction:
    return Fraction(fps).limit_denominator(1001)


def _add_stream(
    container: av.container.OutputContainer,
    codec: Codec,
    rate: Fraction,
    width: int,
    height: int,
    crf: int,
    gop: int,
) -> av.VideoStream:
    stream = container.add_stream(_ENCODERS[codec], rate=rate)  # type: ignore[call-overload]
    stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
    if codec == "h264":
        stream.options = {"crf": str(crf), "g": str(gop), "preset": "fast"}
    else:
        stream.options = {
            "crf": str(crf),
            "preset": "fast",
            "x265-params": f"keyint={gop}:min-keyint={gop}:log-level=error",
        }
    return stream


def to_yuv420(
    picture: NDArray[np.uint8], matrix: Literal["bt601", "bt709"], full_range: bool
) -> NDArray[np.uint8]:
    """A luminance or RGB picture as one yuv420p array of shape (3 H / 2, W)."""
    height, width = picture.shape[:2]
    if picture.ndim == 2:
        luma = picture.astype(np.uint8)
        chroma = np.full((2, height // 2, width // 2), 128, np.uint8)
    else:
        luma, chroma = _rgb_to_yuv(picture.astype(np.float64), matrix, full_range)
    return np.concatenate([luma, chroma.reshape(height // 2, width)], axis=0)


def _rgb_to_yuv(
    rgb: NDArray[np.float64], matrix: Literal["bt601", "bt709"], full_range: bool
) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    kr, kb = _KR_KB[matrix]
    r, g, b = (rgb[..., i] / 255.0 for i in range(3))
    y = kr * r + (1 - kr - kb) * g + kb * b
    pb = (b - y) / (2 * (1 - kb))
    pr = (r - y) / (2 * (1 - kr))
    y_scale, y_off, c_scale = (255.0, 0.0, 255.0) if full_range else (219.0, 16.0, 224.0)
    luma = np.clip(np.rint(y * y_scale + y_off), 0, 255).astype(np.uint8)
    h, w = y.shape
    chroma = np.stack([pb, pr]).reshape(2, h // 2, 2, w // 2, 2).mean(axis=(2, 4))
    chroma_u8 = np.clip(np.rint(chroma * c_scale + 128.0), 0, 255).astype(np.uint8)
    return luma, chroma_u8


def index_picture(index: int, width: int = 640, height: int = 320) -> NDArray[np.uint8]:
    """A luminance picture whose top band encodes `index` in `INDEX_BITS` binary cells."""
    picture = np.full((height, width), 40, np.uint8)
    cell = width // INDEX_BITS
    band = height // 4
    for bit in range(INDEX_BITS):
        if (index >> bit) & 1:
            picture[:band, bit * cell : (bit + 1) * cell] = 220
    # a moving bar gives the encoder real motion between frames
    column = (index * 13) % width
    picture[band:, column : column + 8] = 160
    return picture


def read_index(luma: NDArray[np.uint8]) -> int:
    """The frame index drawn by `index_picture`, read back from a decoded luminance."""
    height, width = luma.shape
    cell = width // INDEX_BITS
    band = height // 4
    cells = luma[: band - 4, : cell * INDEX_BITS].reshape(band - 4, INDEX_BITS, cell)
    bits = cells[:, :, 4:-4].mean(axis=(0, 2)) > 130
    return int(np.sum(bits.astype(np.int64) << np.arange(INDEX_BITS)))


def gaussian_spots(
    height: int,
    width: int,
    u: Sequence[float],
    v: Sequence[float],
    amplitude: Sequence[float],
    sigma: float = 1.0,
    background: float | NDArray[np.float64] = 20.0,
) -> NDArray[np.uint8]:
    """Point-sampled Gaussian spots on a background; spots wrap across the u seam.

    Spot ``i`` adds ``amplitude[i] · exp(-d² / 2σ²)`` at the pixel centres (integer
    coordinates), ``d`` measured with the horizontal distance wrapped to ``[-W/2, W/2)``.
    """
    canvas = np.zeros((height, width)) + background
    cols = np.arange(width)
    rows = np.arange(height)
    for uu, vv, a in zip(u, v, amplitude, strict=True):
        du = (cols - uu + width / 2) % width - width / 2
        dv = rows - vv
        canvas += a * np.exp(-(dv[:, None] ** 2 + du[None, :] ** 2) / (2 * sigma**2))
    return np.clip(np.rint(canvas), 0, 255).astype(np.uint8)


def sample_offsets(path: str | Path) -> list[tuple[int, int]]:
    """(byte offset, size) of every video sample of an MP4, in decode order."""
    with av.open(str(path)) as container:
        entries = container.streams.video[0].index_entries
        return [(e.pos, e.size) for e in entries]


def overwrite_sample(path: str | Path, sample: int, fill: int = 0xFF) -> None:
    """Overwrite the first 64 bytes of one sample (its NAL length prefix included)."""
    pos, size = sample_offsets(path)[sample]
    with open(path, "r+b") as fh:
        fh.seek(pos)
        fh.write(bytes([fill]) * min(64, size))


def truncate(path: str | Path, fraction: float) -> None:
    """Cut a file to `fraction` of its size, like an interrupted upload."""
    data = Path(path).read_bytes()
    Path(path).write_bytes(data[: int(len(data) * fraction)])


def with_creation_time(source: str | Path, target: str | Path, creation_time: str) -> Path:
    """A copy of a video (packets as they are) whose container says when it was created."""
    target = Path(target)
    with av.open(str(source)) as src, av.open(str(target), "w") as dst:
        dst.metadata["creation_time"] = creation_time
        stream = dst.add_stream_from_template(src.streams.video[0])
        for packet in src.demux(src.streams.video[0]):
            if packet.dts is not None:
                packet.stream = stream
                dst.mux(packet)
    return target
