"""The night's clock: when camera 1's frame 0 was recorded, in UTC, and the sunset.

Frames are counted on camera 1's clock (``time_s = frame / fps``, DESIGN.md); this
module places that count in real time. The start comes from, in order:

1. the night's ``start_time`` (an override the team gives), or
2. the ``creation_time`` camera 1's first chapter file carries (MP4/MOV ``mvhd``, read
   at probe, whole seconds), read as the night's ``camera_clock`` says: wall-clock
   time in the night's time zone (GoPro) or UTC.

If neither gives an absolute time, the time is unknown and `NightClock.warnings` says
why; nothing is guessed (a local clock time is never taken for UTC). The sunset is the
one nearest to the start (`pipeline.sun`), when latitude and longitude are known.

``work/clock.json`` holds the result; `pipeline.stages.link` and the patterns stage
turn frames into ``timestamp_utc`` (ISO 8601, milliseconds, ``Z``) and
``minutes_after_sunset`` with it.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pipeline.jsonio import read_json, write_json
from pipeline.night import NightInfo
from pipeline.probe import StereoProbe
from pipeline.sun import nearest_sunset

#: Creation times before this year are unset camera clocks (epochs 1904 or 1970).
FIRST_PLAUSIBLE_YEAR = 2000


@dataclass(frozen=True)
class NightClock:
    """Where camera 1's frame count sits in real time (None: unknown).

    Attributes
    ----------
    start_utc : datetime or None
        When camera 1's frame 0 was recorded (aware, UTC).
    source : str or None
        Where ``start_utc`` comes from, in words.
    sunset_utc : datetime or None
        The sunset nearest to the start, at the night's location.
    time_zone : str or None
        The night's IANA time zone, for showing local times.
    warnings : tuple of str
        Why the time or the sunset is unknown, or anything odd about them.
    """

    start_utc: dt.datetime | None = None
    source: str | None = None
    sunset_utc: dt.datetime | None = None
    time_zone: str | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)

    def seconds(self, frames: ArrayLike, fps: float) -> NDArray[np.float64]:
        """Seconds on camera 1's clock of the given camera-1 frames."""
        return np.asarray(frames, dtype=np.float64) / fps

    def timestamps(self, frames: ArrayLike, fps: float) -> NDArray[np.str_]:
        """ISO 8601 UTC times (``2026-06-13T01:02:03.456Z``) of frames; ``""`` if unknown."""
        frames = np.asarray(frames)
        if self.start_utc is None:
            return np.full(frames.shape, "", dtype="<U1")
        start_ms = round(self.start_utc.timestamp() * 1000)
        ms = start_ms + np.round(self.seconds(frames, fps) * 1000).astype(np.int64)
        stamps = np.datetime_as_string(ms.astype("datetime64[ms]"), unit="ms")
        return np.char.add(stamps, "Z")

    def minutes_after_sunset(self, frames: ArrayLike, fps: float) -> NDArray[np.float64]:
        """Minutes from the night's sunset to the frames (negative before it); NaN if unknown."""
        frames = np.asarray(frames)
        if self.start_utc is None or self.sunset_utc is None:
            return np.full(frames.shape, np.nan)
        offset_s = (self.start_utc - self.sunset_utc).total_seconds()
        return (offset_s + self.seconds(frames, fps)) / 60.0

    def local(self, when: dt.datetime) -> dt.datetime:
        """`when` in the night's time zone (UTC if that is unknown)."""
        zone = NightInfo(time_zone=self.time_zone).zone
        return when.astimezone(zone or dt.UTC)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form; times as ISO 8601 strings; `from_dict` reverses it."""
        return {
            "start_utc": _iso(self.start_utc),
            "source": self.source,
            "sunset_utc": _iso(self.sunset_utc),
            "start_minutes_after_sunset": (
                round((self.start_utc - self.sunset_utc).total_seconds() / 60.0, 2)
                if self.start_utc and self.sunset_utc
                else None
            ),
            "start_local": _iso(self.local(self.start_utc)) if self.start_utc else None,
            "time_zone": self.time_zone,
            "warnings": list(self.warnings),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> NightClock:
        return cls(
            start_utc=_parse(data.get("start_utc")),
            source=data.get("source"),
            sunset_utc=_parse(data.get("sunset_utc")),
            time_zone=data.get("time_zone"),
            warnings=tuple(data.get("warnings", ())),
        )

    def save(self, path: Path) -> None:
        write_json(path, self.to_dict())

    @classmethod
    def load(cls, path: Path) -> NightClock:
        return cls.from_dict(read_json(path))


def _iso(when: dt.datetime | None) -> str | None:
    return None if when is None else when.isoformat(timespec="milliseconds")


def _parse(text: str | None) -> dt.datetime | None:
    return None if not text else dt.datetime.fromisoformat(text)


def parse_creation_time(text: str) -> dt.datetime | None:
    """A container's ``creation_time`` as written (ISO 8601), or None if unreadable.

    The result is naive when the text has no offset; a trailing ``Z`` gives UTC.
    """
    try:
        return dt.datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        return None


def _absolute(when: dt.datetime, night: NightInfo, what: str) -> tuple[dt.datetime | None, str]:
    """An aware datetime from a wall-clock one in the night's zone, or why not."""
    zone = night.zone
    if when.tzinfo is not None:
        return when, ""
    if zone is None:
        return None, (
            f"{what} is {when:%Y-%m-%d %H:%M:%S} on a local clock whose time zone is unknown: "
            "give the night's time zone to place the recording in UTC"
        )
    return when.replace(tzinfo=zone), ""


def video_start(night: NightInfo, probe: StereoProbe) -> tuple[dt.datetime | None, str, str]:
    """Frame 0 of camera 1 from its first chapter's creation time: (time, source, problem)."""
    video = probe.videos.get(1)
    chapter = video.chapters[0] if video and video.chapters else None
    raw = chapter.creation_time if chapter else None
    if chapter is None or not raw:
        return None, "", "camera 1's video carries no creation time and no start time was given"
    stamp = parse_creation_time(raw)
    if stamp is None:
        return None, "", f"camera 1's creation time {raw!r} ({chapter.path.name}) is unreadable"
    if stamp.year < FIRST_PLAUSIBLE_YEAR:
        return (
            None,
            "",
            (f"camera 1's creation time {raw!r} ({chapter.path.name}) is an unset camera clock"),
        )
    if night.camera_clock == "utc":
        return stamp.replace(tzinfo=dt.UTC), f"creation time of {chapter.path.name} (UTC)", ""
    wall = stamp.replace(tzinfo=None)  # the camera's own clock: its "Z" is not UTC
    what = f"the creation time of {chapter.path.name}"
    start, problem = _absolute(wall, night, what)
    source = f"creation time of {chapter.path.name} (camera clock in {night.time_zone})"
    return start, source if start else "", problem


def night_clock(night: NightInfo, probe: StereoProbe) -> NightClock:
    """Place camera 1's frame 0 in UTC and find the night's sunset (see module doc)."""
    warnings: list[str] = []
    if night.start_time is not None:
        start, problem = _absolute(night.start_time, night, "the start time given")
        source = "start time given for the night" if start else ""
    else:
        start, source, problem = video_start(night, probe)
    if problem:
        warnings.append(f"time of night unknown: {problem}")
    start = start.astimezone(dt.UTC) if start else None
    sunset = None
    if start is not None and night.located:
        assert night.latitude is not None and night.longitude is not None
        sunset = nearest_sunset(start, night.latitude, night.longitude)
        if sunset is None:
            warnings.append("the sun does not set at this place and date: no minutes after sunset")
    elif start is not None:
        warnings.append("the night's latitude and longitude are unknown: no minutes after sunset")
    if start is not None and night.date is not None and night.zone is not None:
        local_date = start.astimezone(night.zone).date()
        if abs((local_date - night.date).days) > 1:
            warnings.append(
                f"the recording starts on {local_date} (local), not on the night's date "
                f"{night.date}: check the camera's clock or the start time"
            )
    return NightClock(
        start_utc=start,
        source=source or None,
        sunset_utc=sunset,
        time_zone=night.time_zone,
        warnings=tuple(warnings),
    )
