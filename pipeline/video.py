"""Decoding of equirectangular camera recordings split into chapter files.

A camera is one or more chapter files played back to back with ONE global, 0-based
frame count: the first frame of chapter 2 continues the count of chapter 1 (CONTRACT,
see DESIGN.md). `probe_video` reads the metadata of every chapter up front and refuses
anything the pipeline cannot use with a `VideoError` naming the file; `iter_frames`
decodes any frame range, seeking to a keyframe instead of decoding from the start.

Frames are handed out as planar YUV: the luminance plane ``y`` (what tracking works
on) and the chroma planes ``u``, ``v`` that `pipeline.patches` needs to build RGB
crops; a whole frame is never converted to RGB.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import av
import numpy as np
from numpy.typing import NDArray

from pipeline.probe import ChapterInfo, VideoError, VideoInfo

#: Relative frame-rate difference tolerated between chapters or cameras: absorbs rounded
#: rate metadata, yet refuses 30 against 30000/1001 fps (0.1 %, a frame every 33 s).
FPS_TOLERANCE = 5e-4

#: Planar 8-bit layouts handed out as they are; anything else is converted to yuv420p.
_PLANAR_FORMATS = frozenset({"yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p"})

# FFmpeg's AVColorSpace codes for the matrices we know.
_MATRIX_BY_COLORSPACE = {1: "bt709", 5: "bt601", 6: "bt601", 9: "bt2020", 10: "bt2020"}
_AVCOL_RANGE_JPEG = 2

Matrix = Literal["bt601", "bt709", "bt2020"]


@dataclass(frozen=True)
class YuvEncoding:
    """How a stream's YUV samples map to RGB.

    Attributes
    ----------
    matrix : {"bt601", "bt709", "bt2020"}
        Luma/chroma matrix (ITU-R BT.601, BT.709 or BT.2020 non-constant luminance).
    full_range : bool
        True for full-range ("JPEG", 0–255) samples, False for limited range
        (luma 16–235, chroma 16–240).
    """

    matrix: Matrix
    full_range: bool


@dataclass(frozen=True, eq=False)
class Frame:
    """One decoded frame as planar YUV.

    Attributes
    ----------
    index : int
        Global 0-based frame index.
    y : ndarray of uint8, shape (H, W)
        Luminance plane (may be a strided view into the decoder's buffer).
    u, v : ndarray of uint8, shape (H / sy, W / sx)
        Chroma planes (Cb, Cr); ``sy``, ``sx`` are the chroma subsampling factors
        (2, 2 for 4:2:0).
    encoding : YuvEncoding
        Matrix and range for converting to RGB.
    key : bool
        The encoder coded the picture whole (a key or intra frame), not from the frames
        before it: its grain is renewed at once.
    """

    index: int
    y: NDArray[np.uint8]
    u: NDArray[np.uint8]
    v: NDArray[np.uint8]
    encoding: YuvEncoding = field(default=YuvEncoding("bt601", False))
    key: bool = False

    @property
    def height(self) -> int:
        return int(self.y.shape[0])

    @property
    def width(self) -> int:
        return int(self.y.shape[1])


# -- probing ---------------------------------------------------------------------------


@dataclass(frozen=True)
class _StreamProps:
    width: int
    height: int
    fps: float


def probe_video(paths: Sequence[str | Path]) -> VideoInfo:
    """Read the metadata of one camera's chapter files and check they are usable.

    Frame counts are exact: they come from the container's sample table (checked
    against the file size, which catches truncated uploads) or, for containers
    without one, from demuxing every packet; nothing is decoded except each chapter's
    first frame.

    Parameters
    ----------
    paths : sequence of path-like
        The camera's chapter files in playback order.

    Returns
    -------
    VideoInfo
        Chapters with their global frame ranges, and the common frame size, rate and
        codec.

    Raises
    ------
    VideoError
        Naming the file: missing or unreadable, not a video, no video stream, no
        frames, truncated, variable frame rate, not equirectangular (width ≠ 2 ×
        height), or chapters that differ in frame size or rate.
    """
    if not paths:
        raise VideoError("no video files given")
    chapters: list[ChapterInfo] = []
    props: list[_StreamProps] = []
    first_frame = 0
    for raw in paths:
        chapter, prop = _probe_chapter(Path(raw), first_frame)
        if props:
            _check_same_stream(chapters[0].path, props[0], chapter.path, prop)
        chapters.append(chapter)
        props.append(prop)
        first_frame = chapter.stop_frame
    codecs = list(dict.fromkeys(ch.codec for ch in chapters))
    return VideoInfo(
        chapters=tuple(chapters),
        width=props[0].width,
        height=props[0].height,
        fps=props[0].fps,
        n_frames=first_frame,
        codec="/".join(codecs),
    )


def check_stereo_pair(cam1: VideoInfo, cam2: VideoInfo) -> None:
    """Refuse two cameras that cannot be processed as a stereo pair.

    Raises
    ------
    VideoError
        If the frame rates differ by more than `FPS_TOLERANCE` (relative) or the frame
        sizes differ; the message gives both values.
    """
    if not math.isclose(cam1.fps, cam2.fps, rel_tol=FPS_TOLERANCE):
        raise VideoError(
            f"the cameras have different frame rates: camera 1 {cam1.fps:.3f} fps "
            f"({cam1.chapters[0].path.name}), camera 2 {cam2.fps:.3f} fps "
            f"({cam2.chapters[0].path.name})"
        )
    if (cam1.width, cam1.height) != (cam2.width, cam2.height):
        raise VideoError(
            f"the cameras have different frame sizes: camera 1 {cam1.width}×{cam1.height} "
            f"({cam1.chapters[0].path.name}), camera 2 {cam2.width}×{cam2.height} "
            f"({cam2.chapters[0].path.name})"
        )


def _check_same_stream(path_a: Path, a: _StreamProps, path_b: Path, b: _StreamProps) -> None:
    if (a.width, a.height) != (b.width, b.height):
        raise VideoError(
            f"{path_b.name}: frame size {b.width}×{b.height} differs from "
            f"{a.width}×{a.height} of the first chapter {path_a.name}"
        )
    if not math.isclose(a.fps, b.fps, rel_tol=FPS_TOLERANCE):
        raise VideoError(
            f"{path_b.name}: frame rate {b.fps:.3f} fps differs from {a.fps:.3f} fps "
            f"of the first chapter {path_a.name}"
        )


def _probe_chapter(path: Path, first_frame: int) -> tuple[ChapterInfo, _StreamProps]:
    with _open(path) as container:
        stream = _video_stream(container, path)
        width, height = stream.codec_context.width, stream.codec_context.height
        if width != 2 * height:
            raise VideoError(
                f"{path.name}: frame size {width}×{height} is not equirectangular "
                "(a 360° video must be exactly twice as wide as it is high)"
            )
        rate = stream.average_rate or stream.guessed_rate
        if not rate or rate <= 0:
            raise VideoError(f"{path.name}: the frame rate is not recorded in the file")
        fps = float(rate)
        timestamps, video_bytes = _frame_timestamps(container, stream, path)
        if len(timestamps) == 0:
            raise VideoError(f"{path.name}: the video stream has no frames (empty video)")
        _check_constant_rate(timestamps, fps * _tick_s(stream, path), path)
        first_pts = _first_frame_pts(path)
        chapter = ChapterInfo(
            path=path,
            n_frames=len(timestamps),
            first_frame=first_frame,
            codec=stream.codec_context.name,
            first_pts=first_pts,
            creation_time=_creation_time(container, stream),
            video_bytes=video_bytes,
        )
    return chapter, _StreamProps(width, height, fps)


def _creation_time(container: av.container.InputContainer, stream: av.VideoStream) -> str | None:
    """The file's ``creation_time`` tag (container first, then the video stream), as written."""
    for metadata in (container.metadata, stream.metadata):
        value = metadata.get("creation_time")
        if value and value.strip():
            return str(value).strip()
    return None


def _open(path: Path) -> av.container.InputContainer:
    if not path.exists():
        raise VideoError(f"{path.name}: file not found ({path})")
    if not path.is_file():
        raise VideoError(f"{path.name}: not a regular file ({path})")
    if path.stat().st_size == 0:
        raise VideoError(f"{path.name}: empty file (0 bytes)")
    try:
        return av.open(str(path), mode="r")
    except PermissionError:
        raise VideoError(f"{path.name}: cannot read the file (permission denied)") from None
    except (av.FFmpegError, OSError) as exc:
        raise VideoError(
            f"{path.name}: not a readable video file: the container cannot be parsed "
            f"({_reason(exc)}); it may be truncated, corrupt or not a video at all"
        ) from None


def _video_stream(container: av.container.InputContainer, path: Path) -> av.VideoStream:
    if not container.streams.video:
        found = ", ".join(s.type for s in container.streams) or "no streams at all"
        raise VideoError(f"{path.name}: no video stream in the file (found: {found})")
    return container.streams.video[0]


def _frame_timestamps(
    container: av.container.InputContainer, stream: av.VideoStream, path: Path
) -> tuple[NDArray[np.int64], int]:
    """Decode timestamps of every frame, without decoding, and the bytes of the frames.

    MP4/MOV carry a sample table: one entry per frame, exact, read without touching the
    media data; the byte range of the last entries tells whether the file is complete.
    Other containers are demuxed packet by packet (one packet per frame for H.264/HEVC),
    stamped by presentation time: Matroska leaves the decode time of the first packets
    (the decoder's delay) unset.
    """
    entries = stream.index_entries
    if len(entries) > 0 and len(entries) == stream.frames:
        kept = [e for e in entries if not e.is_discard]
        _check_complete(kept, path)
        return np.array([e.timestamp for e in kept], dtype=np.int64), sum(e.size for e in kept)
    try:
        packets = [
            (p.dts if p.pts is None else p.pts, p.size) for p in container.demux(stream) if p.size
        ]
    except av.FFmpegError as exc:
        raise VideoError(f"{path.name}: cannot read packets ({_reason(exc)})") from None
    stamps = np.array([t for t, _ in packets if t is not None], dtype=np.int64)
    return np.sort(stamps), sum(size for _, size in packets)


def _check_complete(entries: Sequence[av.index.IndexEntry], path: Path) -> None:
    size = path.stat().st_size
    ends = np.array([e.pos + e.size for e in entries], dtype=np.int64)
    missing = np.flatnonzero(ends > size)
    if len(missing):
        raise VideoError(
            f"{path.name}: truncated: the file lists {len(entries)} frames but ends at "
            f"byte {size} inside frame {missing[0]}, so only {missing[0]} frames are "
            "present; upload the complete file"
        )


def _check_constant_rate(timestamps: NDArray[np.int64], frame_ticks_inv: float, path: Path) -> None:
    """Refuse variable-frame-rate files: frame indices are derived from timestamps."""
    if len(timestamps) < 2:
        return
    ts = np.sort(timestamps)
    position = (ts - ts[0]) * frame_ticks_inv  # in frames
    deviation = np.abs(position - np.arange(len(ts)))
    worst = int(np.argmax(deviation))
    if deviation[worst] >= 0.5:
        raise VideoError(
            f"{path.name}: variable frame rate: frame {worst} is {deviation[worst]:.2f} "
            "frame periods off the nominal rate; re-encode at a constant frame rate"
        )


def _first_frame_pts(path: Path) -> int:
    with _open(path) as container:
        stream = _video_stream(container, path)
        try:
            frame = next(container.decode(stream), None)
        except av.FFmpegError as exc:
            raise VideoError(
                f"{path.name}: the first frame cannot be decoded ({_reason(exc)})"
            ) from None
    if frame is None or frame.pts is None:
        raise VideoError(f"{path.name}: the first frame cannot be decoded (no picture)")
    return int(frame.pts)


def _tick_s(stream: av.VideoStream, path: Path) -> float:
    """Duration of one timestamp tick in seconds."""
    if not stream.time_base:
        raise VideoError(f"{path.name}: the video stream has no time base")
    return float(stream.time_base)


def _reason(exc: BaseException) -> str:
    return getattr(exc, "strerror", None) or str(exc)


# -- decoding --------------------------------------------------------------------------


def iter_frames(info: VideoInfo, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
    """Decode the global frame range ``[start, stop)`` across chapter files.

    Each chapter is entered by seeking to a keyframe at or before the first wanted
    frame and decoding forward. FFmpeg's frame threads decode the next frames while
    the consumer works on this one (a separate decoding thread feeding a bounded queue
    was measured to add nothing on top: 0.98× on 2 cores); memory holds a few frames
    whatever the range.

    Parameters
    ----------
    info : VideoInfo
        Probe result of the camera (see `probe_video`).
    start, stop : int
        Global frame range; ``stop=None`` means to the end.

    Yields
    ------
    Frame
        Consecutive frames ``start, start + 1, …, stop - 1``.

    Raises
    ------
    ValueError
        If the range is not within ``[0, info.n_frames]``.
    VideoError
        If a chapter yields fewer frames than probed, skips a frame, or the decoder
        fails; the message names the file and the frame.
    """
    stop = info.checked_range(start, stop)
    if start == stop:
        return
    for i in info.chapters_for(start, stop):
        ch = info.chapters[i]
        lo = max(start, ch.first_frame) - ch.first_frame
        hi = min(stop, ch.stop_frame) - ch.first_frame
        yield from _decode_chapter(ch, lo, hi, info.fps)


def _decode_chapter(chapter: ChapterInfo, start: int, stop: int, fps: float) -> Iterator[Frame]:
    """Frames ``[start, stop)`` of one chapter (chapter-local indices)."""
    name = chapter.path.name
    expected = start
    with _open(chapter.path) as container:
        stream = _video_stream(container, chapter.path)
        stream.thread_type = "AUTO"
        timeline = _Timeline(chapter.first_pts, fps * _tick_s(stream, chapter.path))
        encoding: YuvEncoding | None = None
        try:
            for picture in _decode_from(container, stream, chapter, timeline, start):
                k = timeline.index(picture.pts)
                if k < expected:
                    continue  # pre-roll between the keyframe and the first wanted frame
                if k > expected:
                    raise VideoError(
                        f"{name}: frame {expected} (global {chapter.first_frame + expected}) "
                        f"is missing: the decoder jumped to frame {k}; the file is corrupt"
                    )
                encoding = encoding or _yuv_encoding(picture)
                yield _to_frame(picture, chapter.first_frame + k, encoding)
                expected += 1
                if expected == stop:
                    return
        except av.FFmpegError as exc:  # reading the file, not decoding a packet
            raise _decode_error(chapter, expected, exc) from None
    raise VideoError(
        f"{name}: truncated or corrupt at frame {expected} (of {chapter.n_frames} probed)"
    )


@dataclass(frozen=True)
class _Timeline:
    """Chapter-local frame index <-> presentation timestamp, at a constant frame rate."""

    first_pts: int
    frames_per_tick: float

    def index(self, pts: int | None) -> int:
        # A picture without timestamp cannot be placed: treat it as pre-roll.
        return -1 if pts is None else round((pts - self.first_pts) * self.frames_per_tick)

    def pts(self, index: int) -> int:
        return self.first_pts + math.floor(index / self.frames_per_tick)


def _decode_from(
    container: av.container.InputContainer,
    stream: av.VideoStream,
    chapter: ChapterInfo,
    timeline: _Timeline,
    start: int,
) -> Iterator[av.VideoFrame]:
    """Pictures from a keyframe at or before chapter frame `start` to the end.

    Demuxers seek on decode timestamps and open-GOP streams drop leading pictures after
    a seek, so the first picture can land after `start`: then seek further back.
    """
    margin = 0
    while True:
        target = max(0, start - margin)
        if start > 0:
            container.seek(timeline.pts(target), stream=stream, backward=True)
        pictures = _pictures(container, stream, chapter, timeline)
        first = next(pictures, None)
        if first is None:
            return
        if target == 0 or timeline.index(first.pts) <= start:
            yield first
            yield from pictures
            return
        margin = max(2 * margin, 16)


def _pictures(
    container: av.container.InputContainer,
    stream: av.VideoStream,
    chapter: ChapterInfo,
    timeline: _Timeline,
) -> Iterator[av.VideoFrame]:
    """Decoded pictures in presentation order; a decoder error names its packet's frame."""
    for packet in container.demux(stream):
        try:
            pictures = packet.decode()
        except av.FFmpegError as exc:
            frame = timeline.index(packet.pts) if packet.pts is not None else chapter.n_frames
            raise _decode_error(chapter, frame, exc) from None
        yield from pictures


def _decode_error(chapter: ChapterInfo, frame: int, exc: BaseException) -> VideoError:
    # Frame-threaded decoders report an error a few packets late: hence "near".
    return VideoError(
        f"{chapter.path.name}: corrupt video data, decoder error near frame {frame} (global "
        f"{chapter.first_frame + frame}, of {chapter.n_frames} probed): {_reason(exc)}"
    )


def _yuv_encoding(picture: av.VideoFrame) -> YuvEncoding:
    """Matrix and range from the stream's tags; untagged HD video is taken as BT.709
    and SD as BT.601 (what encoders assume), untagged range as limited unless the
    pixel format is a full-range ``yuvj`` one."""
    matrix: Matrix = _MATRIX_BY_COLORSPACE.get(  # type: ignore[assignment]
        int(picture.colorspace), "bt709" if picture.height >= 720 else "bt601"
    )
    full = int(picture.color_range) == _AVCOL_RANGE_JPEG or picture.format.name.startswith("yuvj")
    return YuvEncoding(matrix, full)


def _to_frame(picture: av.VideoFrame, index: int, encoding: YuvEncoding) -> Frame:
    if picture.format.name not in _PLANAR_FORMATS:
        # One thread: the decoder's frame threads keep every core busy already.
        picture = picture.reformat(format="yuv420p", threads=1)
    y, u, v = (_plane_array(p) for p in picture.planes[:3])
    key = bool(picture.key_frame) or picture.pict_type == av.video.frame.PictureType.I
    return Frame(index=index, y=y, u=u, v=v, encoding=encoding, key=key)


def _plane_array(plane: av.video.plane.VideoPlane) -> NDArray[np.uint8]:
    """Zero-copy view of a plane; it keeps the decoder picture alive while referenced."""
    rows = np.frombuffer(memoryview(plane), dtype=np.uint8, count=plane.line_size * plane.height)
    return rows.reshape(plane.height, plane.line_size)[:, : plane.width]
