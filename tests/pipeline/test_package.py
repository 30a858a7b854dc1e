"""The night's Frictionless Data Package, checked with the `frictionless` library."""

from __future__ import annotations

import datetime as dt
import json
import zipfile
from pathlib import Path

import frictionless
import numpy as np

from pipeline.clock import NightClock
from pipeline.night import NightInfo
from pipeline.package import FIELDS, folder_files, write_package
from pipeline.results import write_flash_patterns

NIGHT = NightInfo(
    site="Elkmont, Little River trail",
    date=dt.date(2026, 6, 12),
    latitude=35.65,
    longitude=-83.58,
    time_zone="America/New_York",
    camera_model="GoPro Max",
)
CLOCK = NightClock(
    start_utc=dt.datetime(2026, 6, 13, 1, 30, tzinfo=dt.UTC),
    sunset_utc=dt.datetime(2026, 6, 13, 0, 50, tzinfo=dt.UTC),
)


def result_folder(out: Path, extra_column: bool = False) -> Path:
    """A small result folder written by the pipeline's own writers (and by hand)."""
    out.mkdir()
    header = "x,y,z,frame,time_s,streak_id,trajectory_id,gap_m,range_m,timestamp_utc,"
    header += "minutes_after_sunset" + (",colour" if extra_column else "")
    stamps = CLOCK.timestamps([10, 11], 30.0)
    rows = [
        f"1.0,2.0,0.5,10,0.3333,0,0,0.001,2.3,{stamps[0]},40.0055",
        f"1.1,2.0,0.5,11,0.3667,0,0,0.001,2.4,{stamps[1]},40.0061",
    ]
    if extra_column:
        rows = [r + ",green" for r in rows]
    (out / "trajectories.csv").write_text("\n".join([header, *rows]) + "\n")
    rows_by_trajectory = {
        "trajectory_id": np.array([0]),
        "first_frame": np.array([10]),
        "last_frame": np.array([11]),
        "first_time_s": np.array([10 / 30]),
        "last_time_s": np.array([11 / 30]),
        "n_points": np.array([2]),
        "n_flashes": np.array([1]),
        "flash_duration_median_s": np.array([2 / 30]),
        "flash_duration_iqr_s": np.array([0.0]),
        "ifi_median_s": np.array([np.nan]),
        "n_trains": np.array([1]),
        "path_length_m": np.array([0.1]),
        "mean_speed_mps": np.array([3.0]),
        "mean_height_m": np.array([np.nan]),
    }
    write_flash_patterns(out / "flash_patterns.csv", rows_by_trajectory, 30.0, CLOCK)
    for camera in (1, 2):
        (out / f"flashes_cam{camera}.csv").write_text(
            "frame,x,y,area,peak,flash_probability\n10,100.5,80.25,4,120,0.99\n"
        )
    calibration = {
        "delay_frames": 3,
        "separation_m": 1.5,
        "camera_height_m": 1.2,
        "rotation": np.eye(3).tolist(),
        "translation": [1, 0, 0],
        "fps": 30.0,
    }
    (out / "calibration.json").write_text(json.dumps(calibration))
    (out / "report").mkdir()
    (out / "report" / "summary.json").write_text("{}")
    return out


def test_the_package_describes_every_field_and_validates(tmp_path: Path) -> None:
    out = result_folder(tmp_path / "night")
    summary = {"parameters": {"chunk_s": 60}, "patterns": {"ifi_s": {"median": 0.55}}}
    calibration = json.loads((out / "calibration.json").read_text())
    descriptor, archive = write_package(out, NIGHT, calibration, summary)
    package = json.loads(descriptor.read_text())
    assert package["night"]["site"] == NIGHT.site
    assert package["night"]["latitude"] == 35.65 and package["night"]["date"] == "2026-06-12"
    assert package["rig"] == {
        **package["rig"],
        "camera_model": "GoPro Max",
        "camera_height_m": 1.2,
        "separation_m": 1.5,
    }
    assert package["software"]["name"] == "firefly3d"
    assert package["software"]["parameters"] == {"chunk_s": 60}
    assert "Sarfati" in package["citation"]
    tables = {r["path"]: r for r in package["resources"] if r.get("schema")}
    assert set(tables) == {
        "trajectories.csv",
        "flash_patterns.csv",
        "flashes_cam1.csv",
        "flashes_cam2.csv",
    }
    for name, resource in tables.items():
        for field in resource["schema"]["fields"]:
            assert field["type"] != "any" and field["description"], (name, field)
            assert field["name"] in FIELDS[name]
    units = {f["name"]: f.get("unit") for f in tables["trajectories.csv"]["schema"]["fields"]}
    assert units["x"] == "m" and units["time_s"] == "s" and units["minutes_after_sunset"] == "min"

    report = frictionless.validate(descriptor)
    assert report.valid, report.flatten(["rowNumber", "fieldName", "type", "note"])
    with zipfile.ZipFile(archive) as zf:
        assert sorted(zf.namelist()) == sorted(
            [f.name for f in folder_files(out)] + ["datapackage.json"]
        )


def test_a_file_that_breaks_its_schema_is_caught(tmp_path: Path) -> None:
    out = result_folder(tmp_path / "night", extra_column=True)
    descriptor, _ = write_package(out, NIGHT, None, None)
    fields = json.loads(descriptor.read_text())["resources"][0]["schema"]["fields"]
    assert fields[-1] == {
        "name": "colour",
        "type": "any",
        "description": "(a column firefly3d does not describe)",
    }
    assert frictionless.validate(descriptor).valid
    # A frame that is not an integer breaks trajectories.csv's schema.
    path = out / "trajectories.csv"
    path.write_text(path.read_text().replace(",10,0.3333,", ",ten,0.3333,"))
    descriptor, _ = write_package(out, NIGHT, None, None)
    report = frictionless.validate(descriptor)
    assert not report.valid
    assert {e[0] for e in report.flatten(["type"])} == {"type-error"}
