"""The night as a self-describing Frictionless Data Package (``datapackage.json``).

One builder for both ways a night leaves the system: ``firefly3d process --package``
writes ``datapackage.json`` (and a zip of the package) into the result folder, and the
service adds the same ``datapackage.json`` to the "download all" zip of a job. Both hand
`datapackage` the result files (name, size, CSV header), the night's metadata
(`pipeline.night.NightInfo`), ``calibration.json`` and the run summary.

The package follows the Data Package standard (v1, with the v2 ``$schema``):
every CSV is a ``tabular-data-resource`` whose Table Schema gives each field its type,
its unit (a custom ``unit`` property) and a description; the other files are plain
resources. Package-level properties describe the night (site, date, latitude,
longitude, time zone, clock), the rig (camera model, height, separation, pose and
delay), the software (name, version, parameters), the night's flash-pattern figures,
and cite the method.

Columns we do not know (an extra column another tracker wrote) are listed with type
``any`` rather than left out, so the package always matches its files.
"""

from __future__ import annotations

import datetime as dt
import re
import zipfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from pipeline import __version__
from pipeline.artifacts import (
    CALIBRATION_JSON,
    CAMERAS,
    DATAPACKAGE_JSON,
    FLASH_PATTERNS_CSV,
    REPORT_DIR,
    TRAJECTORIES_CSV,
    flashes_name,
)
from pipeline.night import NightInfo

#: The result files a package holds (with everything under ``report/``).
RESULT_FILES = (
    TRAJECTORIES_CSV,
    FLASH_PATTERNS_CSV,
    *(flashes_name(c) for c in CAMERAS),
    CALIBRATION_JSON,
)

#: The method to cite.
CITATION = (
    "Sarfati, R., Hayes, J. C., Sarfati, É., & Peleg, O. (2020). Spatio-temporal "
    "reconstruction of emergent flash synchronization in firefly swarms via stereoscopic "
    "360-degree cameras. Journal of the Royal Society Interface, 17(170), 20200179. "
    "https://doi.org/10.1098/rsif.2020.0179"
)
CITATION_PATTERNS = (
    "Sarfati, R., Hayes, J. C., & Peleg, O. (2021). Self-organization in natural swarms "
    "of Photinus carolinus synchronous fireflies. Science Advances, 7(28), eabg9259. "
    "https://doi.org/10.1126/sciadv.abg9259"
)

Field = tuple[str, str | None, str]  # (Table Schema type, unit, description)

_TIME_UTC = (
    "datetime",
    None,
    "When the flash was recorded, UTC (ISO 8601, milliseconds): camera 1's frame 0 "
    "placed by the night's clock (see the package's night.clock) plus time_s; empty when "
    "the recording's time is unknown",
)
_AFTER_SUNSET = (
    "number",
    "min",
    "Minutes from the night's sunset (NOAA solar equations at the night's latitude and "
    "longitude) to the flash, negative before sunset; empty when the time or place is "
    "unknown",
)

#: Known columns of the CSV results.
FIELDS: dict[str, dict[str, Field]] = {
    TRAJECTORIES_CSV: {
        "x": ("number", "m", "Position east-west in camera 1's frame (camera 1 at the origin)"),
        "y": ("number", "m", "Position in camera 1's frame (horizontal, orthogonal to x)"),
        "z": (
            "number",
            "m",
            "Height relative to camera 1 (z up); ground at minus the camera height",
        ),
        "frame": ("integer", "frame", "Camera 1's frame, 0-based, global across chapters"),
        "time_s": ("number", "s", "frame / fps: time on camera 1's clock since its frame 0"),
        "streak_id": ("integer", None, "A streak: consecutive lit frames of one flash"),
        "trajectory_id": (
            "integer",
            None,
            "A trajectory: streaks of one firefly linked in time (gap <= 1 s) and space (< 1 m)",
        ),
        "gap_m": ("number", "m", "Ray gap of the triangulation (an error measure)"),
        "range_m": ("number", "m", "Distance from camera 1"),
        "range_sd_m": (
            "number",
            "m",
            "Standard deviation of range_m from the detections' position errors (first "
            "order; the pose's error not included)",
        ),
        "timestamp_utc": _TIME_UTC,
        "minutes_after_sunset": _AFTER_SUNSET,
    },
    FLASH_PATTERNS_CSV: {
        "trajectory_id": ("integer", None, "The trajectory (trajectories.csv)"),
        "first_frame": ("integer", "frame", "Camera 1's frame of its first flash"),
        "last_frame": ("integer", "frame", "Camera 1's frame of its last lit point"),
        "first_time_s": ("number", "s", "first_frame / fps"),
        "last_time_s": ("number", "s", "last_frame / fps"),
        "n_points": ("integer", None, "Triangulated points (lit frames)"),
        "n_flashes": ("integer", None, "Flashes: streaks, joined across one missed frame"),
        "flash_duration_median_s": (
            "number",
            "s",
            "Median flash duration (first to last lit "
            "frame, inclusive, / fps), flashes cut by the recording's "
            "ends left out",
        ),
        "flash_duration_iqr_s": ("number", "s", "Interquartile range of its flash durations"),
        "ifi_median_s": (
            "number",
            "s",
            "Median inter-flash interval: onset to onset of consecutive flashes within a train",
        ),
        "n_trains": (
            "integer",
            None,
            "Trains (bursts): flashes separated by more than the "
            "train gap (parameters.patterns.train_gap_s) start a new one",
        ),
        "path_length_m": ("number", "m", "Length of the path through its points in time order"),
        "mean_speed_mps": ("number", "m/s", "path_length_m / (last_time_s - first_time_s)"),
        "mean_height_m": (
            "number",
            "m",
            "Mean height above the ground (z + camera height; "
            "empty when the camera height is unknown)",
        ),
        "timestamp_utc": (
            _TIME_UTC[0],
            None,
            "When its first flash was recorded, UTC "
            "(ISO 8601); empty when the recording's time is unknown",
        ),
        "minutes_after_sunset": (
            _AFTER_SUNSET[0],
            "min",
            "Minutes from the night's sunset "
            "to its first flash; empty when time or place is unknown",
        ),
    },
    **{
        flashes_name(camera): {
            "frame": (
                "integer",
                "frame",
                f"Camera {camera}'s frame, 0-based, global across chapters",
            ),
            "x": (
                "number",
                "px",
                "Column u of the flash's centroid (equirectangular: azimuth = 2 pi u / width)",
            ),
            "y": (
                "number",
                "px",
                "Row v of the flash's centroid (polar angle = pi v / height, 0 = zenith)",
            ),
            "area": ("integer", "px", "Pixels of the blob above the tracking threshold"),
            "peak": (
                "number",
                "grey level",
                "Brightest foreground value (frame minus background, 0-255)",
            ),
            "flash_probability": (
                "number",
                None,
                "The classifier's probability that the candidate is a firefly flash (0-1)",
            ),
        }
        for camera in CAMERAS
    },
}

_DESCRIPTIONS = {
    TRAJECTORIES_CSV: "One row per triangulated flash point (one firefly lit in one frame), "
    "linked into streaks and trajectories. Metres in camera 1's frame, z up.",
    FLASH_PATTERNS_CSV: "One row per trajectory: its flash pattern (durations, inter-flash "
    "intervals, trains), speed and height.",
    CALIBRATION_JSON: "Temporal and spatial calibration of the camera pair found from the "
    "flashes: delay_frames (camera-1 frame k = camera-2 frame k + delay), rotation "
    "(3x3, row-major) and unit translation of camera 2, separation_m, fps, frame size, "
    "residuals.",
    **{
        flashes_name(c): f"Flashes accepted in camera {c} (before triangulation): pixel "
        "positions per frame."
        for c in CAMERAS
    },
}


@dataclass(frozen=True)
class PackageFile:
    """A file of the package: its name in the package, size, and CSV header."""

    name: str
    size: int
    header: tuple[str, ...] = ()


def is_package_file(name: str) -> bool:
    """Whether a result-folder file belongs in the package (results and report)."""
    return name in RESULT_FILES or name.startswith(f"{REPORT_DIR}/")


def csv_header(first_bytes: bytes) -> tuple[str, ...]:
    """Column names from the start of a CSV file."""
    line = first_bytes.split(b"\n", 1)[0].decode("utf-8").strip()
    return tuple(name.strip() for name in line.split(",")) if line else ()


def slug(text: str) -> str:
    """Lower-case letters, digits, ``.``, ``_`` and ``-`` (a package ``name``)."""
    return re.sub(r"[^a-z0-9._-]+", "-", text.lower()).strip("-") or "night"


def archive_stem(night: NightInfo) -> str:
    """``firefly3d-<site>-<date>``: the package's name and its zip's file name."""
    site = re.sub(r"[^A-Za-z0-9]+", "-", night.site or "").strip("-")[:40] or "site"
    return f"firefly3d-{site}-{night.date or 'undated'}"


def _schema(name: str, header: Sequence[str]) -> dict[str, Any]:
    known = FIELDS.get(name, {})
    fields = []
    for column in header:
        kind, unit, description = known.get(
            column, ("any", None, "(a column firefly3d does not describe)")
        )
        entry: dict[str, Any] = {"name": column, "type": kind, "description": description}
        if kind == "datetime":
            entry["format"] = "any"  # ISO 8601 with milliseconds and Z
        if unit:
            entry["unit"] = unit
        fields.append(entry)
    return {"fields": fields, "missingValues": [""]}


def _resource(file: PackageFile) -> dict[str, Any]:
    path = PurePosixPath(file.name)
    resource: dict[str, Any] = {
        "name": slug(path.as_posix().replace("/", "-").replace(".", "-")),
        "path": file.name,
        "bytes": file.size,
    }
    if path.suffix == ".csv":
        resource.update(
            profile="tabular-data-resource",
            format="csv",
            mediatype="text/csv",
            encoding="utf-8",
            schema=_schema(file.name, file.header),
        )
    elif path.suffix == ".json":
        resource.update(format="json", mediatype="application/json")
    elif path.suffix == ".png":
        resource.update(format="png", mediatype="image/png")
    description = _DESCRIPTIONS.get(file.name)
    if description is None and file.name.startswith(f"{REPORT_DIR}/"):
        description = "Report: run summary (JSON) or plot (PNG)."
    if description:
        resource["description"] = description
    return resource


def _rig(calibration: Mapping[str, Any], night: NightInfo) -> dict[str, Any]:
    keys = ("delay_frames", "delay_confidence", "rotation", "translation", "fps")
    return {
        "camera_model": night.camera_model,
        "camera_height_m": calibration.get("camera_height_m"),
        "separation_m": calibration.get("separation_m"),
        "frame_width_px": calibration.get("width"),
        "frame_height_px": calibration.get("height"),
        **{key: calibration.get(key) for key in keys},
    }


def datapackage(
    files: Iterable[PackageFile],
    night: NightInfo,
    calibration: Mapping[str, Any] | None = None,
    summary: Mapping[str, Any] | None = None,
    created: dt.datetime | None = None,
) -> dict[str, Any]:
    """The ``datapackage.json`` of a night's results.

    Parameters
    ----------
    files : iterable of PackageFile
        The files the package holds (`is_package_file`), CSVs with their header.
    night : NightInfo
        Site, date, place, clock and camera model.
    calibration : mapping, optional
        ``calibration.json`` (separation, camera height, pose, delay, fps).
    summary : mapping, optional
        The run summary (``report/summary.json``): parameters, clock, flash patterns.
    created : datetime, optional
        When the results were made (default: now).
    """
    summary = summary or {}
    created = (created or dt.datetime.now(dt.UTC)).astimezone(dt.UTC)
    stem = archive_stem(night)
    title = f"Firefly flashes in 3D: {night.site or 'unnamed site'}, {night.date or 'undated'}"
    return {
        "$schema": "https://datapackage.org/profiles/2.0/datapackage.json",
        "profile": "data-package",
        "name": slug(stem),
        "title": title,
        "description": "3D flash trajectories and flash patterns of a firefly swarm, "
        "reconstructed with firefly3d from a stereo pair of 360-degree videos.",
        "version": "1.0.0",
        "created": created.isoformat(timespec="seconds").replace("+00:00", "Z"),
        "keywords": ["fireflies", "Lampyridae", "flash patterns", "3D trajectories"],
        "sources": [
            {"title": CITATION, "path": "https://doi.org/10.1098/rsif.2020.0179"},
            {"title": CITATION_PATTERNS, "path": "https://doi.org/10.1126/sciadv.abg9259"},
        ],
        "citation": CITATION,
        "night": {
            "site": night.site,
            "date": night.date.isoformat() if night.date else None,
            "latitude": night.latitude,
            "longitude": night.longitude,
            "time_zone": night.time_zone,
            "notes": night.notes or None,
            "clock": summary.get("clock"),
        },
        "rig": _rig(calibration or {}, night),
        "software": {
            "name": "firefly3d",
            "version": __version__,
            "parameters": summary.get("parameters"),
        },
        "flash_patterns": summary.get("patterns"),
        "resources": [_resource(f) for f in files],
    }


def folder_files(out_dir: Path) -> list[PackageFile]:
    """The package files present in a result folder, in `RESULT_FILES` order, then the
    report's files."""
    names = [name for name in RESULT_FILES if (out_dir / name).is_file()]
    report = out_dir / REPORT_DIR
    if report.is_dir():
        names += sorted(p.relative_to(out_dir).as_posix() for p in report.rglob("*") if p.is_file())
    files = []
    for name in names:
        path = out_dir / name
        header: tuple[str, ...] = ()
        if name.endswith(".csv"):
            with open(path, "rb") as fh:
                header = csv_header(fh.readline())
        files.append(PackageFile(name, path.stat().st_size, header))
    return files


def write_package(
    out_dir: Path,
    night: NightInfo,
    calibration: Mapping[str, Any] | None,
    summary: Mapping[str, Any] | None,
) -> tuple[Path, Path]:
    """Write ``datapackage.json`` into a result folder and zip the package beside it.

    Returns the paths of ``datapackage.json`` and of the zip
    (``<out_dir>/<archive_stem>.zip``: the package files and ``datapackage.json``).
    """
    import json

    files = folder_files(out_dir)
    package = datapackage(files, night, calibration, summary)
    descriptor = out_dir / DATAPACKAGE_JSON
    descriptor.write_text(json.dumps(package, indent=2) + "\n", encoding="utf-8")
    archive = out_dir / f"{archive_stem(night)}.zip"
    with zipfile.ZipFile(archive, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for file in files:
            zf.write(out_dir / file.name, file.name)
        zf.write(descriptor, DATAPACKAGE_JSON)
    return descriptor, archive
