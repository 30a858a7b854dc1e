"""Accuracy of a run against the simulator's ground truth.

Measures what biologists rely on: the delay and pose, how many flashes seen by both
cameras were reconstructed accurately (recall), how many output points are real flashes
(precision), whether trajectories mix fireflies (purity), and the per-camera detection
recall and precision of the tracker + classifier.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from pipeline import artifacts
from pipeline.detections import Detections
from pipeline.geometry import angle_between, pixel_to_bearing, rotation_angle
from pipeline.results import read_calibration, read_trajectories
from pipeline.simulate import GroundTruth

#: A triangulated flash is "reconstructed" when within this fraction of its true range.
RANGE_TOLERANCE = 0.02
#: An output point "is" a true flash when within this fraction of its range (identity).
IDENTITY_TOLERANCE = 0.05
#: A 2D detection "is" a true flash when within this many pixels (at the equator).
DETECTION_TOLERANCE_PX = 2.0

#: The targets of the project (issue 2) for simulated 640×320 recordings.
TARGETS = {
    "delay_error_frames": ("==", 0),
    "rotation_error_deg": ("<=", 0.3),
    "translation_error_deg": ("<=", 1.5),
    "recall_within_2pct": (">=", 0.90),
    "precision": (">=", 0.98),
    "trajectory_purity": (">=", 0.95),
}


@dataclass(frozen=True)
class Accuracy:
    """Figures of one run compared with its ground truth (fractions in [0, 1])."""

    delay_error_frames: int
    rotation_error_deg: float
    translation_error_deg: float
    n_truth_flashes: int
    recall_within_2pct: float
    n_points: int
    precision: float
    median_range_error_pct: float
    trajectory_purity: float
    n_trajectories: int
    detection_recall_cam1: float
    detection_precision_cam1: float
    detection_recall_cam2: float
    detection_precision_cam2: float

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)

    def failures(self, relaxed: Mapping[str, float] | None = None) -> list[str]:
        """Targets this run misses, as readable lines (empty when all are met).

        ``relaxed`` replaces the level of some `TARGETS` (same comparison).
        """
        values = self.to_dict()
        missed = []
        levels = {
            name: (op, (relaxed or {}).get(name, level)) for name, (op, level) in TARGETS.items()
        }
        for name, (op, target) in levels.items():
            value = values[name]
            ok = {"==": value == target, "<=": value <= target, ">=": value >= target}[op]
            if not ok:
                missed.append(f"{name} = {value:.4g}, target {op} {target}")
        return missed


def evaluate_run(out_dir: Path, truth: GroundTruth) -> Accuracy:
    """Compare a run folder's results with the ground truth of its recording."""
    calibration = read_calibration(out_dir / artifacts.CALIBRATION_JSON)
    trajectories = read_trajectories(out_dir / artifacts.TRAJECTORIES_CSV)
    xyz = np.column_stack([trajectories["x"], trajectories["y"], trajectories["z"]])
    frame = trajectories["frame"]
    match = match_points(xyz, frame, truth)
    recall = _fraction(match.found(RANGE_TOLERANCE))
    is_true = match.point_is_true
    point_range = match.point_range
    range_error = np.abs(np.linalg.norm(xyz, axis=1) - point_range)[is_true] / point_range[is_true]
    firefly = truth.flashes.firefly_id[match.truth_rows]
    purity = _purity(trajectories["trajectory_id"][is_true], firefly[match.nearest[is_true]])
    det = {c: Detections.from_csv(out_dir / artifacts.flashes_name(c)) for c in artifacts.CAMERAS}
    recall1, precision1 = detection_scores(det[1], truth, 1)
    recall2, precision2 = detection_scores(det[2], truth, 2)
    return Accuracy(
        delay_error_frames=int(calibration.delay_frames - truth.delay_frames),
        rotation_error_deg=float(
            np.degrees(rotation_angle(calibration.pose.rotation, truth.pose.rotation))
        ),
        translation_error_deg=float(
            np.degrees(angle_between(calibration.pose.translation, truth.pose.translation))
        ),
        n_truth_flashes=len(match.truth_rows),
        recall_within_2pct=recall,
        n_points=len(frame),
        precision=_fraction(is_true) if len(frame) else 0.0,
        median_range_error_pct=float(100 * np.median(range_error)) if len(range_error) else np.nan,
        trajectory_purity=purity,
        n_trajectories=len(np.unique(trajectories["trajectory_id"])),
        detection_recall_cam1=recall1,
        detection_precision_cam1=precision1,
        detection_recall_cam2=recall2,
        detection_precision_cam2=precision2,
    )


@dataclass(frozen=True)
class PointMatch:
    """Triangulated points matched with the true flash-frames seen by both cameras.

    Attributes
    ----------
    truth_rows : ndarray of int64
        Rows of ``truth.flashes`` visible in both cameras (the 3D truth).
    gap : ndarray
        Per truth row, distance (metres) to the nearest output point of the same
        camera-1 frame (inf where that frame has none).
    true_range : ndarray
        Per truth row, its distance from camera 1.
    nearest : ndarray of int64
        Per output point, the index (into ``truth_rows``) of the nearest true flash of
        its frame (meaningless where ``point_range`` is inf).
    point_range : ndarray
        Per output point, the range of that nearest true flash (inf where its frame
        has none).
    point_is_true : ndarray of bool
        Per output point: within `IDENTITY_TOLERANCE` of its range from that flash.
    """

    truth_rows: np.ndarray
    gap: np.ndarray
    true_range: np.ndarray
    nearest: np.ndarray
    point_range: np.ndarray
    point_is_true: np.ndarray

    def found(self, tolerance: float) -> np.ndarray:
        """Per truth row: an output point lies within ``tolerance`` × its range."""
        return self.gap <= tolerance * self.true_range


def match_points(xyz: np.ndarray, frame: np.ndarray, truth: GroundTruth) -> PointMatch:
    """Match output points (``xyz`` metres, camera-1 ``frame``) with the true flashes
    seen by both cameras, both ways (nearest of the same frame, `_nearest_same_frame`)."""
    truth_rows = np.flatnonzero(_seen_by_both(truth))
    true_xyz = truth.flashes.position()[truth_rows]
    true_frame = truth.flashes.frame1[truth_rows]
    true_range = np.linalg.norm(true_xyz, axis=1)
    gap_truth, _ = _nearest_same_frame(xyz, frame, true_xyz, true_frame)
    gap_point, nearest = _nearest_same_frame(true_xyz, true_frame, xyz, frame)
    matched = np.isfinite(gap_point)
    point_range = np.where(matched, true_range[np.minimum(nearest, len(true_range) - 1)], np.inf)
    return PointMatch(
        truth_rows=truth_rows,
        gap=gap_truth,
        true_range=true_range,
        nearest=nearest,
        point_range=point_range,
        point_is_true=matched & (gap_point <= IDENTITY_TOLERANCE * point_range),
    )


@dataclass(frozen=True)
class DetectionMatch:
    """One camera's detections matched with its visible true flash-frames.

    Attributes
    ----------
    truth_rows : ndarray of int64
        Rows of ``truth.flashes`` visible in the camera.
    found : ndarray of bool
        Per truth row: a detection of the same frame within `DETECTION_TOLERANCE_PX`.
    true_detection : ndarray of bool
        Per detection: a visible true flash of the same frame within that tolerance.
    distance : ndarray
        Per detection, the distance (equatorial pixels) to the nearest visible true
        flash of its frame (inf where there is none).
    error : ndarray
        Per truth row, the distance (equatorial pixels) to the nearest detection of its
        frame (inf where there is none): the position error where ``found``.
    flash_row : ndarray of int64
        Per detection, the row of ``truth.flashes`` it is a detection of (the nearest
        visible true flash of its frame), -1 where it is not ``true_detection``.
    """

    truth_rows: np.ndarray
    found: np.ndarray
    true_detection: np.ndarray
    distance: np.ndarray
    error: np.ndarray
    flash_row: np.ndarray

    @property
    def recall(self) -> float:
        return _fraction(self.found)

    @property
    def precision(self) -> float:
        return _fraction(self.true_detection)


def camera_points(u: np.ndarray, v: np.ndarray, width: int) -> np.ndarray:
    """Pixels as points on a sphere whose equator is ``width`` long: chords between
    them measure angles in equatorial pixels, across the seam and near the poles."""
    scale = width / (2 * np.pi)  # chord length of one equatorial pixel ≈ 1
    return pixel_to_bearing(u, v, width) * scale


def match_detections(detections: Detections, truth: GroundTruth, camera: int) -> DetectionMatch:
    """Match one camera's detections with its visible true flashes, both ways.

    A detection matches a visible true flash of the same frame within
    `DETECTION_TOLERANCE_PX` (angular distance expressed in equatorial pixels, so the
    seam and the poles are handled).
    """
    frame, u, v, visible = truth.flashes.in_camera(camera)
    rows = np.flatnonzero(visible)
    true_pts = camera_points(u[rows], v[rows], truth.width)
    det_pts = camera_points(detections.x, detections.y, truth.width)
    gap_truth, _ = _nearest_same_frame(det_pts, detections.frame, true_pts, frame[rows])
    gap_det, nearest = _nearest_same_frame(true_pts, frame[rows], det_pts, detections.frame)
    true_detection = gap_det <= DETECTION_TOLERANCE_PX
    flash_row = np.full(len(detections), -1, dtype=np.int64)
    flash_row[true_detection] = rows[nearest[true_detection]]
    return DetectionMatch(
        truth_rows=rows,
        found=gap_truth <= DETECTION_TOLERANCE_PX,
        true_detection=true_detection,
        distance=gap_det,
        error=gap_truth,
        flash_row=flash_row,
    )


def detection_scores(
    detections: Detections, truth: GroundTruth, camera: int
) -> tuple[float, float]:
    """Recall and precision of one camera's accepted detections against its visible
    flashes (`match_detections`)."""
    match = match_detections(detections, truth, camera)
    return match.recall, match.precision


def _seen_by_both(truth: GroundTruth) -> np.ndarray:
    f = truth.flashes
    return f.visible1 & f.visible2


def nearest_same_frame(
    ref_xyz: np.ndarray, ref_frame: np.ndarray, query_xyz: np.ndarray, query_frame: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each query point to the nearest reference point of the same frame,
    and that point's index.

    Frames are a fourth coordinate scaled far beyond any spatial distance, so the
    KD-tree never pairs points of different frames; inf where a frame has no reference.
    """
    if len(query_xyz) == 0:
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    if len(ref_xyz) == 0:
        return np.full(len(query_xyz), np.inf), np.zeros(len(query_xyz), dtype=np.int64)
    span = 10.0 * (np.abs(ref_xyz).max() + np.abs(query_xyz).max() + 1.0)
    tree = cKDTree(np.column_stack([ref_xyz, ref_frame * span]))
    dist, index = tree.query(np.column_stack([query_xyz, query_frame * span]), k=1)
    too_far = dist >= span / 2  # nearest lies in another frame
    return np.where(too_far, np.inf, dist), index


_nearest_same_frame = nearest_same_frame


def _purity(trajectory_id: np.ndarray, firefly_id: np.ndarray) -> float:
    """Share of points that belong to their trajectory's majority firefly."""
    if len(trajectory_id) == 0:
        return 0.0
    pairs, counts = np.unique(
        np.column_stack([trajectory_id, firefly_id]), axis=0, return_counts=True
    )
    order = np.lexsort((-counts, pairs[:, 0]))
    first = np.unique(pairs[order, 0], return_index=True)[1]
    return float(counts[order][first].sum() / len(trajectory_id))


def _fraction(mask: np.ndarray) -> float:
    return float(np.mean(mask)) if len(mask) else 0.0


def format_accuracy(accuracy: Accuracy) -> str:
    """A readable table of the figures, with the project's targets where it has one."""
    lines = []
    for name, value in accuracy.to_dict().items():
        target = TARGETS.get(name)
        shown = f"{value:.4f}" if isinstance(value, float) else str(value)
        suffix = f"   (target {target[0]} {target[1]})" if target else ""
        lines.append(f"  {name:<26} {shown:>10}{suffix}")
    missed = accuracy.failures()
    lines.append("  all targets met" if not missed else "  MISSED: " + "; ".join(missed))
    return "\n".join(lines)
