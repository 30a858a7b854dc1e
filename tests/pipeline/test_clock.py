"""The night's clock: sunset (NOAA equations), video creation times, ISO timestamps."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from pipeline.clock import NightClock, night_clock
from pipeline.night import NightInfo
from pipeline.probe import StereoProbe
from pipeline.sun import nearest_sunset, sunset_utc
from pipeline.video import probe_video
from tests.pipeline.video_factory import with_creation_time, write_video

UTC = dt.UTC


def minutes_between(a: dt.datetime, b: dt.datetime) -> float:
    return abs((a - b).total_seconds()) / 60


@pytest.mark.parametrize(
    ("date", "lat", "lon", "expected"),
    [
        # Astral's documented example (NOAA's equations): London, 2009-04-22, 19:08:41 UTC.
        (dt.date(2009, 4, 22), 51.5, -0.116, dt.datetime(2009, 4, 22, 19, 8, 41, tzinfo=UTC)),
        # Greenwich, June solstice 2024: 21:21 BST in the almanacs.
        (dt.date(2024, 6, 21), 51.4769, -0.0005, dt.datetime(2024, 6, 21, 20, 21, tzinfo=UTC)),
    ],
)
def test_sunset_matches_published_times(date, lat, lon, expected) -> None:
    found = sunset_utc(date, lat, lon)
    assert found is not None
    assert minutes_between(found, expected) < 1.5


def test_no_sunset_in_polar_day_and_the_night_after_midnight_keeps_its_sunset() -> None:
    assert sunset_utc(dt.date(2026, 6, 21), 78.2, 15.6) is None  # Svalbard, midnight sun
    # Great Smoky Mountains: sunset 20:50 EDT on 12 June = 00:50 UTC on the 13th. A
    # recording at 23:30 EDT and one at 20:00 EDT (before sunset) both belong to it.
    for local_hour in (23, 20):
        start = dt.datetime(2026, 6, 12, local_hour, 30, tzinfo=dt.timezone(dt.timedelta(hours=-4)))
        sunset = nearest_sunset(start, 35.6, -83.5)
        assert sunset is not None
        local = sunset.astimezone(start.tzinfo)
        assert local.date() == dt.date(2026, 6, 12)
        assert dt.time(20, 40) < local.time() < dt.time(21, 0)


def video_with_creation_time(path: Path, creation_time: str) -> Path:
    """A tiny equirectangular video whose container says when it was created."""
    write_video(path, [np.zeros((32, 64), np.uint8)] * 3, fps=30.0)
    return with_creation_time(path, path.with_name(f"tagged-{path.name}"), creation_time)


def probe_of(path: Path) -> StereoProbe:
    info = probe_video([path])
    return StereoProbe(info.width, info.height, info.fps, {1: info.n_frames}, {1: info})


def test_a_gopro_creation_time_gives_timestamp_utc(tmp_path: Path) -> None:
    # A GoPro writes its local wall-clock time, tagged "Z": 21:30:05 in New York (EDT).
    video = video_with_creation_time(tmp_path / "GS010001.mp4", "2026-06-12T21:30:05.000000Z")
    probe = probe_of(video)
    assert probe.videos[1].chapters[0].creation_time == "2026-06-12T21:30:05.000000Z"
    night = NightInfo(time_zone="America/New_York", latitude=35.6, longitude=-83.5)
    clock = night_clock(night, probe)
    assert clock.start_utc == dt.datetime(2026, 6, 13, 1, 30, 5, tzinfo=UTC)
    assert clock.warnings == ()
    stamps = clock.timestamps([0, 30, 45], 30.0)
    assert stamps.tolist() == [
        "2026-06-13T01:30:05.000Z",
        "2026-06-13T01:30:06.000Z",
        "2026-06-13T01:30:06.500Z",
    ]
    after = clock.minutes_after_sunset([0], 30.0)[0]
    assert after == pytest.approx((clock.start_utc - clock.sunset_utc).total_seconds() / 60)
    assert 35 < after < 45  # sunset about 20:50 EDT
    # A camera that writes true UTC.
    utc = night_clock(NightInfo(camera_clock="utc"), probe)
    assert utc.start_utc == dt.datetime(2026, 6, 12, 21, 30, 5, tzinfo=UTC)
    assert np.isnan(utc.minutes_after_sunset([0], 30.0)).all()  # place unknown
    assert any("latitude and longitude" in w for w in utc.warnings)
    # The round trip through work/clock.json keeps everything.
    clock.save(tmp_path / "clock.json")
    assert NightClock.load(tmp_path / "clock.json") == clock


def test_an_unknown_time_is_stated_never_guessed(tmp_path: Path) -> None:
    video = video_with_creation_time(tmp_path / "GS010001.mp4", "2026-06-12T21:30:05.000000Z")
    clock = night_clock(NightInfo(), probe_of(video))  # local camera clock, zone unknown
    assert clock.start_utc is None
    assert clock.timestamps([0, 1], 30.0).tolist() == ["", ""]
    assert "time zone is unknown" in clock.warnings[0]
    untagged = write_video(tmp_path / "plain.mp4", [np.zeros((32, 64), np.uint8)] * 2)
    clock = night_clock(NightInfo(time_zone="Europe/Paris"), probe_of(untagged))
    assert clock.start_utc is None
    assert "no creation time" in clock.warnings[0]


def test_a_given_start_time_overrides_the_videos(tmp_path: Path) -> None:
    video = video_with_creation_time(tmp_path / "GS010001.mp4", "2026-06-12T21:30:05.000000Z")
    night = NightInfo(time_zone="Europe/Paris", start_time=dt.datetime(2026, 6, 12, 22, 0))
    clock = night_clock(night, probe_of(video))
    assert clock.start_utc == dt.datetime(2026, 6, 12, 20, 0, tzinfo=UTC)  # CEST = UTC+2
    assert clock.source == "start time given for the night"
    with pytest.raises(ValidationError, match="no UTC offset"):
        NightInfo(start_time=dt.datetime(2026, 6, 12, 22, 0))
    with pytest.raises(ValidationError, match="unknown time zone"):
        NightInfo(time_zone="Mars/Olympus_Mons")
