"""Names of the files of a run folder (a CLI ``--out`` folder, or a job's storage prefix).

The CONTRACT result files sit at the top of the folder; intermediates that stages pass
to each other live under ``work/``. Names are deterministic per stage (and per camera
and frame range for tracking), so re-running a stage overwrites exactly its outputs.
"""

from __future__ import annotations

CAMERAS = (1, 2)

PROBE_JSON = "work/probe.json"
SYNC_JSON = "work/sync.json"
CALIBRATION_PAIRS_NPZ = "work/calibration_pairs.npz"
POINTS_NPZ = "work/points.npz"
CALIBRATION_JSON = "calibration.json"
TRAJECTORIES_CSV = "trajectories.csv"
REPORT_DIR = "report"
SUMMARY_JSON = "report/summary.json"
METRICS_DIR = "work/metrics"


def chunk_name(camera: int, start: int, stop: int) -> str:
    """Detections of all candidates of one tracked frame range."""
    return f"work/tracking/cam{camera}/{start:08d}-{stop:08d}.npz"


def chunk_metrics_name(camera: int, start: int, stop: int) -> str:
    """Timing and counts of one tracked frame range."""
    return f"work/tracking/cam{camera}/{start:08d}-{stop:08d}.json"


def candidates_name(camera: int) -> str:
    """Every candidate blob of a camera, with its flash probability."""
    return f"work/candidates_cam{camera}.npz"


def flashes_name(camera: int) -> str:
    """Accepted detections of a camera (CONTRACT file)."""
    return f"flashes_cam{camera}.csv"


def metrics_name(stage: str, camera: int | None = None) -> str:
    """Metrics and warnings a stage recorded (per camera for merge)."""
    suffix = "" if camera is None else f"_cam{camera}"
    return f"{METRICS_DIR}/{stage}{suffix}.json"
