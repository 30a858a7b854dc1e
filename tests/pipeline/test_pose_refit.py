"""The pose refitted on the stereo matches of the accepted flashes, and its stage."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.artifacts import (
    CALIBRATION_JSON,
    POSE_JSON,
    REFIT_PAIRS_NPZ,
    SYNC_JSON,
    flashes_name,
)
from pipeline.detections import Detections
from pipeline.geometry import Pose, bearing_to_pixel, rotation_angle
from pipeline.graph import StageContext, Unit
from pipeline.params import PoseParams, ProcessParams, TriangulationParams
from pipeline.pose import CalibrationPairs, PoseEstimate, estimate_pose
from pipeline.pose_refit import jackknife_scaled, stereo_match_pairs
from pipeline.results import Calibration, write_calibration
from pipeline.stages import refit
from tests.pipeline.test_pose import jitter

SEPARATION = 1.5
WIDTH = 640
TRUTH = Pose(Rotation.from_rotvec(np.radians([0.5, -1.0, 2.0])).as_matrix(), [0.0, 1.0, 0.0])
#: The first pose: the truth turned by 0.5° about an axis in the horizon plane.
FIRST = Pose(
    Rotation.from_rotvec(np.radians([0.3, 0.4, 0.0])).as_matrix() @ TRUTH.rotation, [0.0, 1.0, 0.0]
)


def night(
    seed: int, frames: int = 150, per_frame: int = 4, faint_error_deg: float = 0.3
) -> tuple[Detections, Detections]:
    """Accepted flashes of both cameras: `per_frame` fireflies a frame, 2–15 m away
    within 40° of the horizon, placed to 0.02° at 20 σ; every other one is a faint
    flash (6 σ) misplaced by `faint_error_deg` in camera 1."""
    rng = np.random.default_rng(seed)
    n = frames * per_frame
    azimuth = rng.uniform(-np.pi, np.pi, n)
    elevation = np.radians(rng.uniform(-40, 40, n))
    direction = np.column_stack(
        [
            np.cos(elevation) * np.cos(azimuth),
            np.cos(elevation) * np.sin(azimuth),
            np.sin(elevation),
        ]
    )
    points = rng.uniform(2.0, 15.0, (n, 1)) * direction
    in_camera2 = TRUTH.world_to_camera2(points, SEPARATION)
    bearing2 = in_camera2 / np.linalg.norm(in_camera2, axis=1, keepdims=True)
    faint = np.arange(n) % 2 == 1
    bearing1 = jitter(rng, direction, 0.02)
    bearing1[faint] = jitter(rng, direction[faint], faint_error_deg)
    snr = np.where(faint, 6.0, 20.0)
    frame = np.repeat(np.arange(frames), per_frame)
    return (
        Detections.from_columns(frame, *bearing_to_pixel(bearing1, WIDTH), snr=snr),
        Detections.from_columns(
            frame, *bearing_to_pixel(jitter(rng, bearing2, 0.02), WIDTH), snr=snr
        ),
    )


def refitted(
    det1: Detections, det2: Detections, min_snr: float
) -> tuple[PoseEstimate, CalibrationPairs]:
    """The pose fitted on the stereo matches made under `FIRST`, and those matches."""
    pairs = stereo_match_pairs(
        det1, det2, 0, FIRST, WIDTH, SEPARATION, TriangulationParams(), min_snr
    )
    return estimate_pose(pairs), pairs


def rotation_error_deg(pose: Pose) -> float:
    return float(np.degrees(rotation_angle(pose.rotation, TRUTH.rotation)))


def test_the_matches_of_every_accepted_flash_correct_a_pose_half_a_degree_off() -> None:
    det1, det2 = night(1)
    params = PoseParams()
    estimate, pairs = refitted(det1, det2, params.refit_min_snr)
    assert rotation_error_deg(FIRST) > 0.45
    assert rotation_error_deg(estimate.pose) < 0.03
    # The matches of the bright flashes only (the floor is 8 σ): nearly all of them.
    assert 0.9 * 300 <= len(pairs) <= 300 and np.all(np.diff(pairs.frame1) >= 0)
    # With no floor the faint flashes join the fit.
    every, _ = refitted(det1, det2, 0.0)
    assert every.n_pairs > 1.8 * len(pairs)


def test_the_covariance_is_scaled_up_to_the_jackknife_only() -> None:
    det1, det2 = night(2)
    estimate, _ = refitted(det1, det2, PoseParams().refit_min_snr)
    se = estimate.stats["rotation_se_deg"]
    for jackknife, scale in ((2 * se, 4.0), (0.5 * se, 1.0), (float("nan"), 1.0)):
        stats = estimate.stats | {"rotation_jackknife_se_deg": jackknife}
        scaled = jackknife_scaled(replace(estimate, stats=stats))
        np.testing.assert_allclose(scaled, scale * estimate.covariance)


def stage_folder(tmp_path: Path, det1: Detections, det2: Detections) -> StageContext:
    """A run folder holding the first pose (`FIRST`), the delay and the accepted flashes."""
    (tmp_path / "work").mkdir()
    first = Calibration(0, 1.0, FIRST, SEPARATION, 30.0, WIDTH, WIDTH // 2)
    fit = {
        "n_calibration_pairs": 40,
        "n_calibration_inliers": 38,
        "residuals": {"median_deg": 0.03},
    }
    extra = fit | {"calibration_min_snr": None, "pose_fits": [], "camera_height_m": 1.2}
    write_calibration(tmp_path / POSE_JSON, first, extra | {"warnings": ["pose warned"]})
    (tmp_path / SYNC_JSON).write_text(json.dumps({"delay_frames": 0, "warnings": ["delay warned"]}))
    det1.to_csv(tmp_path / flashes_name(1))
    det2.to_csv(tmp_path / flashes_name(2))
    return StageContext(tmp_path, Unit("refit"), ProcessParams(), SEPARATION)


def test_the_refit_stage_writes_the_refitted_pose_and_describes_both(tmp_path: Path) -> None:
    result = refit(stage_folder(tmp_path, *night(3)))
    calibration = json.loads((tmp_path / CALIBRATION_JSON).read_text())
    assert (
        rotation_error_deg(Pose(np.array(calibration["rotation"]), calibration["translation"]))
        < 0.03
    )
    assert calibration["first_pose"]["n_calibration_pairs"] == 40
    assert calibration["first_pose"]["rotation"] == FIRST.rotation.tolist()
    assert calibration["n_calibration_pairs"] > 250 and calibration["camera_height_m"] == 1.2
    assert 0.45 < calibration["refit"]["rotation_change_deg"] < 0.55
    # The first fit's warning was about the first pose; the delay's stays.
    assert calibration["warnings"] == ["delay warned"] and result.warnings == []
    assert result.metrics["rotation"] == calibration["rotation"]
    pairs = np.load(tmp_path / REFIT_PAIRS_NPZ)
    assert len(pairs["residuals"]) == calibration["n_calibration_pairs"]
    assert pairs["inliers"].sum() == calibration["n_calibration_inliers"]


def test_without_matches_the_first_pose_stays_with_a_warning(tmp_path: Path) -> None:
    det1, det2 = night(4, frames=3)  # 6 bright matches: too few for a pose
    result = refit(stage_folder(tmp_path, det1, det2))
    calibration = json.loads((tmp_path / CALIBRATION_JSON).read_text())
    assert calibration["rotation"] == FIRST.rotation.tolist() and calibration["refit"] is None
    assert calibration["n_calibration_pairs"] == 40
    (warning,) = result.warnings
    assert "pose of the confident flashes is kept" in warning
    assert len(np.load(tmp_path / REFIT_PAIRS_NPZ)["residuals"]) == 0
    assert calibration["warnings"] == ["pose warned", warning]


def test_the_refit_can_be_switched_off(tmp_path: Path) -> None:
    ctx = stage_folder(tmp_path, *night(5))
    params = ProcessParams.model_validate({"pose": {"refit_from_accepted": False}})
    result = refit(replace(ctx, params=params))
    calibration = json.loads((tmp_path / CALIBRATION_JSON).read_text())
    assert calibration["rotation"] == FIRST.rotation.tolist() and calibration["refit"] is None
    assert result.warnings == [] and calibration["warnings"] == ["pose warned"]
