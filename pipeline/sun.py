"""Sunset times from the NOAA solar calculator's equations (no dependency).

The equations are those of NOAA's Global Monitoring Laboratory solar calculator
("General Solar Position Calculations" after Meeus, *Astronomical Algorithms*): the
sun's declination and the equation of time from the Julian century, then the hour
angle at which the sun's upper limb touches the horizon, with 0.833° for refraction
and the solar semi-diameter. NOAA quotes them as accurate to about a minute between
±72° latitude; we evaluate them at the sunset itself (two fixed-point steps), not at
noon, which keeps them within seconds of the spreadsheet.
"""

from __future__ import annotations

import datetime as dt
import math

#: Solar zenith angle at sunset: 90° plus refraction (34′) and semi-diameter (16′).
SUNSET_ZENITH_DEG = 90.833

_J2000 = dt.datetime(2000, 1, 1, 12, tzinfo=dt.UTC)


def _solar_terms(when: dt.datetime) -> tuple[float, float]:
    """The sun's declination (radians) and the equation of time (minutes) at `when`."""
    t = (when - _J2000).total_seconds() / 86400.0 / 36525.0  # Julian centuries since J2000
    mean_long = math.radians((280.46646 + t * (36000.76983 + t * 0.0003032)) % 360.0)
    mean_anom = math.radians(357.52911 + t * (35999.05029 - 0.0001537 * t))
    ecc = 0.016708634 - t * (0.000042037 + 0.0000001267 * t)
    centre = (
        math.sin(mean_anom) * (1.914602 - t * (0.004817 + 0.000014 * t))
        + math.sin(2 * mean_anom) * (0.019993 - 0.000101 * t)
        + math.sin(3 * mean_anom) * 0.000289
    )
    omega = math.radians(125.04 - 1934.136 * t)
    apparent_long = math.radians(
        math.degrees(mean_long) + centre - 0.00569 - 0.00478 * math.sin(omega)
    )
    mean_obliquity = 23 + (26 + (21.448 - t * (46.815 + t * (0.00059 - t * 0.001813))) / 60) / 60
    obliquity = math.radians(mean_obliquity + 0.00256 * math.cos(omega))
    declination = math.asin(math.sin(obliquity) * math.sin(apparent_long))
    y = math.tan(obliquity / 2) ** 2
    eot = 4 * math.degrees(
        y * math.sin(2 * mean_long)
        - 2 * ecc * math.sin(mean_anom)
        + 4 * ecc * y * math.sin(mean_anom) * math.cos(2 * mean_long)
        - 0.5 * y * y * math.sin(4 * mean_long)
        - 1.25 * ecc * ecc * math.sin(2 * mean_anom)
    )
    return declination, eot


def sunset_utc(date: dt.date, latitude: float, longitude: float) -> dt.datetime | None:
    """Sunset on the UTC day `date` at a place (degrees; north and east positive).

    "Sunset" is the sun's solar-day evening crossing of the horizon nearest to the
    place's solar noon on that date; for places far from Greenwich it can fall on the
    next or previous UTC day. Returns None where the sun does not set or rise that day
    (polar day or night).
    """
    noon_minutes = 720.0 - 4.0 * longitude  # solar noon, ignoring the equation of time
    when = dt.datetime.combine(date, dt.time(tzinfo=dt.UTC)) + dt.timedelta(minutes=noon_minutes)
    phi = math.radians(latitude)
    for _ in range(3):  # evaluate the sun's terms at the sunset itself
        declination, eot = _solar_terms(when)
        cos_h = math.cos(math.radians(SUNSET_ZENITH_DEG)) / (
            math.cos(phi) * math.cos(declination)
        ) - math.tan(phi) * math.tan(declination)
        if not -1.0 <= cos_h <= 1.0:
            return None
        hour_angle_deg = math.degrees(math.acos(cos_h))
        minutes = noon_minutes - eot + 4.0 * hour_angle_deg
        when = dt.datetime.combine(date, dt.time(tzinfo=dt.UTC)) + dt.timedelta(minutes=minutes)
    # Whole seconds: the equations are good to a minute at best.
    return (when + dt.timedelta(microseconds=500_000)).replace(microsecond=0)


def nearest_sunset(when: dt.datetime, latitude: float, longitude: float) -> dt.datetime | None:
    """The sunset nearest to `when` (aware datetime) at a place, before or after it.

    A recording started at dusk (before sunset) or after midnight belongs to the same
    evening: the nearest sunset is the night's. None in polar day or night.
    """
    utc = when.astimezone(dt.UTC)
    candidates = [
        sunset_utc(utc.date() + dt.timedelta(days=d), latitude, longitude) for d in (-1, 0, 1)
    ]
    found = [c for c in candidates if c is not None]
    return min(found, key=lambda c: abs((c - utc).total_seconds())) if found else None
