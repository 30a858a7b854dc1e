"""What is known about the night a recording was made: site, date, place, clocks, cameras.

`NightInfo` is metadata, not a processing parameter: the CLI fills it from its night
options, the service from the job's night row, and it reaches the stages through
`pipeline.graph.StageContext.night`. It places the recording in real time (the clock
stage, `pipeline.clock`) and describes the night in the data package
(`pipeline.package`). Every field is optional: what is unknown is left out, and the
outputs say so instead of guessing.

Light module (pydantic and the standard library): the API imports it.
"""

from __future__ import annotations

import datetime as dt
from typing import Literal
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

#: How a camera's clock writes the container's ``creation_time``.
CameraClock = Literal["local", "utc"]


def check_time_zone(name: str) -> str:
    """`name` if it is an IANA time zone known here.

    Raises
    ------
    ValueError
        Naming the value, for an unknown zone or a malformed name.
    """
    try:
        ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError, OSError, TypeError):
        raise ValueError(
            f"unknown time zone {name!r}: give an IANA name such as America/New_York"
        ) from None
    return name


def check_start_time(start: dt.datetime | None, time_zone: str | None) -> None:
    """Refuse a start time that cannot be placed in UTC (no offset, no time zone).

    Raises
    ------
    ValueError
    """
    if start is not None and start.tzinfo is None and time_zone is None:
        raise ValueError(
            f"start time {start.isoformat()} has no UTC offset: give one "
            "(e.g. 2026-06-12T21:30:00-04:00) or the site's time zone"
        )


class NightInfo(BaseModel):
    """A recording session's metadata (all optional; validated; immutable).

    Attributes
    ----------
    site : str or None
        Where, in words.
    date : datetime.date or None
        Local date on which the recording started.
    latitude, longitude : float or None
        Decimal degrees (WGS 84; north and east positive). Both are needed for sunset.
    time_zone : str or None
        IANA time zone of the site (e.g. ``America/New_York``): the zone of the
        cameras' clocks when ``camera_clock`` is ``"local"``, and of a ``start_time``
        given without an offset.
    camera_clock : {"local", "utc"}
        What the video's ``creation_time`` means. GoPro cameras set their clock from
        the phone's local time and write that wall-clock time into the MP4 (tagged as
        UTC, which it is not): ``"local"``, the default, reads it as wall-clock time in
        ``time_zone`` and cannot place it without one. ``"utc"`` is for cameras that
        write true UTC, as the MP4 standard says.
    start_time : datetime or None
        Overrides the videos: when camera 1's first frame (frame 0) was recorded. With
        an offset (``2026-06-12T21:30:00-04:00``) it is absolute; without one it is
        wall-clock time in ``time_zone``.
    camera_model : str or None
        E.g. ``GoPro Max``.
    notes : str
        Free text.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    site: str | None = Field(None, max_length=200, description="Where, in words.")
    date: dt.date | None = Field(None, description="Local date on which the recording started.")
    latitude: float | None = Field(None, ge=-90, le=90, description="Decimal degrees, north +.")
    longitude: float | None = Field(None, ge=-180, le=180, description="Decimal degrees, east +.")
    time_zone: str | None = Field(
        None, max_length=64, description="IANA time zone of the site, e.g. America/New_York."
    )
    camera_clock: CameraClock = Field(
        "local",
        description="'local': the videos' creation_time is the cameras' wall-clock time in "
        "time_zone (GoPro); 'utc': it is UTC.",
    )
    start_time: dt.datetime | None = Field(
        None,
        description="When camera 1's frame 0 was recorded (ISO 8601; without an offset: "
        "wall-clock time in time_zone). Overrides the videos' creation time.",
    )
    camera_model: str | None = Field(None, max_length=100, description="E.g. GoPro Max.")
    notes: str = Field("", max_length=5000, description="Free text.")

    @field_validator("time_zone")
    @classmethod
    def _known_zone(cls, value: str | None) -> str | None:
        return None if value is None else check_time_zone(value)

    @model_validator(mode="after")
    def _placeable_start(self) -> NightInfo:
        check_start_time(self.start_time, self.time_zone)
        return self

    @property
    def zone(self) -> ZoneInfo | None:
        """The site's time zone, if known."""
        return ZoneInfo(self.time_zone) if self.time_zone else None

    @property
    def located(self) -> bool:
        """Whether latitude and longitude are both known (needed for sunset)."""
        return self.latitude is not None and self.longitude is not None
