"""Result files of a run: the CONTRACT formats of DESIGN.md and compact internal ones.

* ``calibration.json``: ``delay_frames``, ``delay_confidence``, ``rotation`` (3×3
  row-major nested lists), ``translation`` (unit 3-vector), ``separation_m``, ``fps``,
  ``width``, ``height``, ``n_calibration_pairs`` and residual statistics.
* ``work/probe.json``: frame size, fps and each camera's length (and video probe).
* ``trajectories.csv``: ``x,y,z,frame,time_s,streak_id,trajectory_id`` then extra
  columns (``gap_m,range_m,range_sd_m,timestamp_utc,minutes_after_sunset``; the last two empty
  when the night's clock or location is unknown); one row per triangulated flash,
  metres in camera 1's frame, camera-1 frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pipeline.clock import NightClock
from pipeline.detections import read_csv, write_csv
from pipeline.geometry import Pose
from pipeline.jsonio import read_json, write_json
from pipeline.trajectories import Linking
from pipeline.triangulate import Points3D

#: Leading columns of ``trajectories.csv`` (CONTRACT), then the extra ones we add.
TRAJECTORY_COLUMNS = ("x", "y", "z", "frame", "time_s", "streak_id", "trajectory_id")
TRAJECTORY_EXTRA_COLUMNS = (
    "gap_m",
    "range_m",
    "range_sd_m",
    "timestamp_utc",
    "minutes_after_sunset",
)
#: Columns of the results CSVs that hold text (ISO 8601 times), not numbers.
TEXT_COLUMNS = ("timestamp_utc",)


@dataclass(frozen=True)
class Calibration:
    """The temporal and spatial calibration of a stereo recording."""

    delay_frames: int
    delay_confidence: float
    pose: Pose
    separation_m: float
    fps: float
    width: int
    height: int
    #: Standard error of the rotation (degrees; 0 where unknown), from the pose fit.
    rotation_se_deg: float = 0.0
    #: Covariance (6 × 6) of the rotation vector and the unit translation
    #: (`pipeline.pose.pose_covariance`); None where unknown.
    covariance: NDArray[np.float64] | None = None

    @property
    def pose_covariance(self) -> NDArray[np.float64]:
        """The pose's covariance; for a calibration of an earlier release, which kept
        only the rotation's standard error, that error on every rotation axis."""
        if self.covariance is not None:
            return self.covariance
        covariance = np.zeros((6, 6))
        covariance[:3, :3] = np.eye(3) * np.radians(self.rotation_se_deg) ** 2
        return covariance


def write_calibration(path: Path, calibration: Calibration, extra: dict[str, Any]) -> None:
    """Write ``calibration.json``: the CONTRACT fields first, then ``extra``."""
    write_json(
        path,
        {
            "delay_frames": int(calibration.delay_frames),
            "delay_confidence": float(calibration.delay_confidence),
            "rotation": calibration.pose.rotation.tolist(),
            "translation": calibration.pose.translation.tolist(),
            "separation_m": float(calibration.separation_m),
            "fps": float(calibration.fps),
            "width": int(calibration.width),
            "height": int(calibration.height),
            **(
                {}
                if calibration.covariance is None
                else {"pose_covariance": _finite_or_none(calibration.covariance)}
            ),
            **extra,
        },
    )


def _finite_or_none(matrix: NDArray[np.float64]) -> list[list[float | None]]:
    """Nested lists for JSON, non-finite entries (an undetermined pose) as null."""
    return [[float(v) if np.isfinite(v) else None for v in row] for row in matrix]


def read_calibration(path: Path) -> Calibration:
    data = read_json(path)
    return Calibration(
        delay_frames=int(data["delay_frames"]),
        delay_confidence=float(data["delay_confidence"]),
        pose=Pose(np.asarray(data["rotation"]), np.asarray(data["translation"])),
        separation_m=float(data["separation_m"]),
        fps=float(data["fps"]),
        width=int(data["width"]),
        height=int(data["height"]),
        rotation_se_deg=float(data.get("residuals", {}).get("rotation_se_deg") or 0.0),
        covariance=None
        if data.get("pose_covariance") is None
        else np.array(data["pose_covariance"], dtype=np.float64),
    )


def save_points(path: Path, points: Points3D) -> None:
    """Lossless ``.npz`` of triangulated points, passed from triangulation to linking."""
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        path,
        xyz=points.xyz,
        frame=points.frame,
        gap_m=points.gap_m,
        range_m=points.range_m,
        range_sd_m=points.range_sd_m,
        index1=points.index1,
        index2=points.index2,
    )


def load_points(path: Path) -> Points3D:
    with np.load(path) as data:
        return Points3D(
            xyz=data["xyz"],
            frame=data["frame"],
            gap_m=data["gap_m"],
            range_m=data["range_m"],
            # Points of earlier releases carry no uncertainty.
            range_sd_m=data["range_sd_m"]
            if "range_sd_m" in data
            else np.full(len(data["frame"]), np.nan),
            index1=data["index1"],
            index2=data["index2"],
        )


def write_trajectories(
    path: Path, points: Points3D, linking: Linking, fps: float, clock: NightClock | None = None
) -> None:
    """Write ``trajectories.csv``: CONTRACT header, then `TRAJECTORY_EXTRA_COLUMNS`.

    ``timestamp_utc`` and ``minutes_after_sunset`` come from the night's `clock` and are
    empty where it does not know them.
    """
    clock = clock or NightClock()
    write_csv(
        path,
        {
            "x": points.xyz[:, 0],
            "y": points.xyz[:, 1],
            "z": points.xyz[:, 2],
            "frame": points.frame,
            "time_s": points.frame / fps,
            "streak_id": linking.streak_id,
            "trajectory_id": linking.trajectory_id,
            "gap_m": points.gap_m,
            "range_m": points.range_m,
            "range_sd_m": points.range_sd_m,
            "timestamp_utc": clock.timestamps(points.frame, fps),
            "minutes_after_sunset": clock.minutes_after_sunset(points.frame, fps),
        },
        formats={
            "minutes_after_sunset": "%.4f",
            "x": "%.4f",
            "y": "%.4f",
            "z": "%.4f",
            "time_s": "%.4f",
            "gap_m": "%.4f",
            "range_m": "%.4f",
            "range_sd_m": "%.4f",
        },
    )


def read_trajectories(path: Path) -> dict[str, np.ndarray]:
    """Columns of a ``trajectories.csv``; integer columns come back as int64."""
    table = read_csv(path, required=TRAJECTORY_COLUMNS, text=TEXT_COLUMNS)
    for name in ("frame", "streak_id", "trajectory_id"):
        table[name] = table[name].astype(np.int64)
    return table


#: Columns of ``flash_patterns.csv``, one row per trajectory (`pipeline.patterns`).
FLASH_PATTERN_COLUMNS = (
    "trajectory_id",
    "first_frame",
    "last_frame",
    "first_time_s",
    "last_time_s",
    "n_points",
    "n_flashes",
    "flash_duration_median_s",
    "flash_duration_iqr_s",
    "ifi_median_s",
    "n_trains",
    "path_length_m",
    "mean_speed_mps",
    "mean_height_m",
    "timestamp_utc",
    "minutes_after_sunset",
)


def write_flash_patterns(
    path: Path, rows: dict[str, np.ndarray], fps: float, clock: NightClock
) -> None:
    """Write ``flash_patterns.csv``: `rows` (`pipeline.patterns.per_trajectory`) and the
    clock's ``timestamp_utc`` / ``minutes_after_sunset`` of each trajectory's first flash."""
    columns: dict[str, ArrayLike] = {
        **rows,
        "timestamp_utc": clock.timestamps(rows["first_frame"], fps),
        "minutes_after_sunset": clock.minutes_after_sunset(rows["first_frame"], fps),
    }
    assert tuple(columns) == FLASH_PATTERN_COLUMNS, tuple(columns)
    formats = {name: "%.4f" for name in columns if name.endswith(("_s", "_m", "_mps"))}
    write_csv(path, columns, formats={**formats, "minutes_after_sunset": "%.4f"})


def read_flash_patterns(path: Path) -> dict[str, np.ndarray]:
    """Columns of a ``flash_patterns.csv`` (times as text, counts as int64)."""
    table = read_csv(path, required=FLASH_PATTERN_COLUMNS[:4], text=TEXT_COLUMNS)
    for name in ("trajectory_id", "first_frame", "last_frame", "n_points", "n_flashes"):
        table[name] = table[name].astype(np.int64)
    return table
