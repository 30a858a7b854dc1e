"""What probing a stereo recording tells: each camera's chapters, frame size, rate, length.

These records are plain data (no decoder needed to read them): the service plans a
job's tracking chunks from them, and every stage reads them from ``work/probe.json``.
`pipeline.video.probe_video` makes a `VideoInfo` from the files themselves.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Self

from pipeline.artifacts import PROBE_JSON
from pipeline.jsonio import read_json, write_json

#: Below this many bits per pixel and frame, compression erases faint flashes: on
#: simulated wind nights (640 px, H.264 at an average bitrate, tuning seed 13) the flash-
#: frames of ≥ 5 σ found were 0.65 at 0.08 bit/px, 0.73 at 0.16 (a GoPro Max at 5.6K,
#: 80 Mbit/s), 0.76 at 0.32 and 0.89 losslessly: the bits go to the swaying leaves and
#: the still dark sky around a faint flash is copied from the frame before.
LOW_BITS_PER_PIXEL = 0.1


class VideoError(ValueError):
    """A video the pipeline refuses or cannot decode; the message names the file."""


@dataclass(frozen=True)
class ChapterInfo:
    """One chapter file of a camera.

    Attributes
    ----------
    path : Path
        The file.
    n_frames : int
        Exact number of frames in the file.
    first_frame : int
        Global index of the chapter's first frame.
    codec : str
        FFmpeg decoder name (``h264``, ``hevc``…).
    first_pts : int
        Presentation timestamp of the first frame, in the stream's time base; frame
        ``i`` of the chapter is the one presented ``i / fps`` seconds later.
    creation_time : str or None
        The container's ``creation_time`` as written (ISO 8601, whole seconds in MP4);
        what clock it is on is the night's to say (`pipeline.clock`). None if absent.
    video_bytes : int or None
        Bytes of the video stream's frames (audio and telemetry left out); None in
        probe records written before it was measured.
    """

    path: Path
    n_frames: int
    first_frame: int
    codec: str
    first_pts: int = 0
    creation_time: str | None = None
    video_bytes: int | None = None

    @property
    def stop_frame(self) -> int:
        """Global index one past the chapter's last frame."""
        return self.first_frame + self.n_frames


@dataclass(frozen=True)
class VideoInfo:
    """Probe result of one camera: its chapters and their common stream properties.

    Attributes
    ----------
    chapters : tuple of ChapterInfo
        In playback order; their frame ranges tile ``[0, n_frames)``.
    width, height : int
        Frame size in pixels (``width = 2 height``, equirectangular).
    fps : float
        Frame rate in frames per second.
    n_frames : int
        Total number of frames over all chapters.
    codec : str
        Decoder name; chapters with different codecs are joined with ``/``.
    """

    chapters: tuple[ChapterInfo, ...]
    width: int
    height: int
    fps: float
    n_frames: int
    codec: str

    @property
    def duration_s(self) -> float:
        return self.n_frames / self.fps

    @property
    def bits_per_pixel(self) -> float | None:
        """Average bits the encoder spent per pixel and frame over all chapters (None
        when a chapter's size is unknown): how much of the sensor's faint detail the
        compression could keep (see `LOW_BITS_PER_PIXEL`)."""
        sizes = [ch.video_bytes for ch in self.chapters]
        if any(size is None for size in sizes) or self.n_frames == 0:
            return None
        return 8.0 * sum(size or 0 for size in sizes) / (self.n_frames * self.width * self.height)

    def chapters_for(self, start: int, stop: int) -> tuple[int, ...]:
        """Indices of the chapters holding any frame of the global range ``[start, stop)``."""
        return tuple(
            i
            for i, ch in enumerate(self.chapters)
            if ch.first_frame < stop and ch.stop_frame > start
        )

    def checked_range(self, start: int, stop: int | None) -> int:
        """The end of the global frame range ``[start, stop)`` (``None``: the last frame).

        Raises
        ------
        ValueError
            If the range is not within ``[0, n_frames]``.
        """
        stop = self.n_frames if stop is None else stop
        if not 0 <= start <= stop <= self.n_frames:
            raise ValueError(
                f"frame range [{start}, {stop}) is outside the video's 0..{self.n_frames} frames"
            )
        return stop

    def with_paths(self, paths: Mapping[int, str | Path]) -> VideoInfo:
        """The same recording with chapter ``i`` read from ``paths[i]`` (e.g. a local copy)."""
        chapters = tuple(
            replace(ch, path=Path(paths[i])) if i in paths else ch
            for i, ch in enumerate(self.chapters)
        )
        return replace(self, chapters=chapters)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (paths as strings); `from_dict` reverses it exactly."""
        return {
            "chapters": [
                {
                    "path": str(ch.path),
                    "n_frames": ch.n_frames,
                    "first_frame": ch.first_frame,
                    "codec": ch.codec,
                    "first_pts": ch.first_pts,
                    "creation_time": ch.creation_time,
                    "video_bytes": ch.video_bytes,
                }
                for ch in self.chapters
            ],
            "width": self.width,
            "height": self.height,
            "fps": self.fps,
            "n_frames": self.n_frames,
            "codec": self.codec,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> VideoInfo:
        """Rebuild a probe result written by `to_dict`.

        Raises
        ------
        VideoError
            If a field is missing or has the wrong type.
        """
        try:
            chapters = tuple(
                ChapterInfo(
                    path=Path(ch["path"]),
                    n_frames=int(ch["n_frames"]),
                    first_frame=int(ch["first_frame"]),
                    codec=str(ch["codec"]),
                    first_pts=int(ch.get("first_pts", 0)),
                    creation_time=ch.get("creation_time"),
                    video_bytes=_optional_int(ch.get("video_bytes")),
                )
                for ch in data["chapters"]
            )
            return cls(
                chapters=chapters,
                width=int(data["width"]),
                height=int(data["height"]),
                fps=float(data["fps"]),
                n_frames=int(data["n_frames"]),
                codec=str(data["codec"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise VideoError(f"malformed video probe record: {exc!r}") from None


def _optional_int(value: Any) -> int | None:
    return None if value is None else int(value)


@dataclass(frozen=True)
class StereoProbe:
    """Frame geometry and timing shared by both cameras, and each camera's length.

    ``videos`` is empty when the run starts from detections (``reconstruct``).
    """

    width: int
    height: int
    fps: float
    n_frames: dict[int, int]
    videos: dict[int, VideoInfo] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "width": self.width,
            "height": self.height,
            "fps": self.fps,
            "n_frames": {str(c): n for c, n in self.n_frames.items()},
            "videos": {str(c): v.to_dict() for c, v in self.videos.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Self:
        return cls(
            width=int(data["width"]),
            height=int(data["height"]),
            fps=float(data["fps"]),
            n_frames={int(c): int(n) for c, n in data["n_frames"].items()},
            videos={int(c): VideoInfo.from_dict(v) for c, v in data.get("videos", {}).items()},
        )

    @classmethod
    def load(cls, workdir: Path) -> Self:
        return cls.from_dict(read_json(workdir / PROBE_JSON))

    def save(self, workdir: Path) -> None:
        write_json(workdir / PROBE_JSON, self.to_dict())
