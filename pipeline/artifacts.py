"""Names of the files of a run folder (a CLI ``--out`` folder, or a job's storage prefix).

The CONTRACT result files sit at the top of the folder; intermediates that stages pass
to each other live under ``work/``. Names are deterministic per stage (and per camera
and frame range for tracking), so re-running a stage overwrites exactly its outputs.

Names that vary are templates with ``{camera}``, ``{start}`` and ``{stop}`` fields: the
stage graph (`pipeline.graph`) declares what each stage reads and writes with them.
"""

from __future__ import annotations

CAMERAS = (1, 2)

PROBE_JSON = "work/probe.json"
#: The night's clock: camera 1's frame 0 in UTC, the sunset (`pipeline.clock`).
CLOCK_JSON = "work/clock.json"
SYNC_JSON = "work/sync.json"
#: The first pose's calibration pairs: camera-1 frame, residual (degrees), inlier.
CALIBRATION_PAIRS_NPZ = "work/calibration_pairs.npz"
#: The refit's pairs (the stereo matches of the accepted flashes), in the same layout;
#: empty when the first pose was kept.
REFIT_PAIRS_NPZ = "work/refit_pairs.npz"
#: The first pose, from the confident flashes (``calibration.json``'s layout): what
#: acceptance matches the cameras with; the pose refitted on the accepted flashes is
#: ``calibration.json`` (`pipeline.pose_refit`).
POSE_JSON = "work/pose.json"
POINTS_NPZ = "work/points.npz"
CALIBRATION_JSON = "calibration.json"
TRAJECTORIES_CSV = "trajectories.csv"
#: One row per trajectory: flash durations, intervals, trains, speed (`pipeline.patterns`).
FLASH_PATTERNS_CSV = "flash_patterns.csv"
#: Frictionless Data Package describing the results (`pipeline.package`).
DATAPACKAGE_JSON = "datapackage.json"
REPORT_DIR = "report"
SUMMARY_JSON = "report/summary.json"
METRICS_DIR = "work/metrics"

#: Detections of all candidates of one tracked frame range.
CHUNK_NPZ = "work/tracking/cam{camera}/{start:08d}-{stop:08d}.npz"
#: Faint peaks of one tracked frame range: spots lit below the candidates' seed level.
FAINT_CHUNK_NPZ = "work/tracking/cam{camera}/faint/{start:08d}-{stop:08d}.npz"
#: Metrics of one tracked frame range.
CHUNK_METRICS_JSON = "work/tracking/cam{camera}/{start:08d}-{stop:08d}.json"
#: Every candidate blob of a camera, with its flash probability.
CANDIDATES_NPZ = "work/candidates_cam{camera}.npz"
#: The acceptance evidence on each candidate of a camera (`pipeline.acceptance`).
EVIDENCE_NPZ = "work/evidence_cam{camera}.npz"
#: The final decision on each candidate of a camera: the evidence model's flash
#: probability (NaN when the rules decided), accepted, matched in the other camera.
ACCEPTANCE_NPZ = "work/acceptance_cam{camera}.npz"
#: Accepted detections of a camera (CONTRACT file).
FLASHES_CSV = "flashes_cam{camera}.csv"


def candidates_name(camera: int) -> str:
    """Every candidate blob of a camera, with its flash probability."""
    return CANDIDATES_NPZ.format(camera=camera)


def flashes_name(camera: int) -> str:
    """Accepted detections of a camera (CONTRACT file)."""
    return FLASHES_CSV.format(camera=camera)
