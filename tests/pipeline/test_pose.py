import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.detections import Detections
from pipeline.geometry import Pose, angle_between, bearing_to_pixel, rotation_angle
from pipeline.params import PoseParams
from pipeline.pose import (
    CalibrationPairs,
    PoseError,
    baseline_warnings,
    calibrate_pose,
    calibration_pairs,
    essential_matrix_pose,
    estimate_pose,
    fit_warnings,
    rotation_se_deg,
    standard_errors_deg,
    translation_se_deg,
    worst_axis_covariance,
)

SEPARATION = 1.5
WIDTH = 640


def scene(
    rng: np.random.Generator, translation: list[float], n: int = 400
) -> tuple[Pose, np.ndarray, np.ndarray, np.ndarray]:
    """A side-by-side pose (a few degrees of rotation) and exact bearings of points 1–15 m
    from camera 1 (in front of camera 2 too)."""
    pose = Pose(Rotation.from_rotvec(np.radians([1.0, -2.0, 3.0])).as_matrix(), translation)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = rng.uniform(1.0, 15.0, (n, 1)) * direction
    in_camera2 = pose.world_to_camera2(points, SEPARATION)
    bearing2 = in_camera2 / np.linalg.norm(in_camera2, axis=1, keepdims=True)
    return pose, points, direction, bearing2


def jitter(rng: np.random.Generator, bearing: np.ndarray, sigma_deg: float) -> np.ndarray:
    """Bearings with isotropic angular noise of ``sigma_deg`` per axis."""
    noise = np.radians(sigma_deg) * rng.normal(size=bearing.shape)
    noise -= np.sum(noise * bearing, axis=1, keepdims=True) * bearing
    moved = bearing + noise
    return moved / np.linalg.norm(moved, axis=1, keepdims=True)


def errors_deg(est_pose: Pose, truth: Pose) -> tuple[float, float]:
    rotation = np.degrees(rotation_angle(est_pose.rotation, truth.rotation))
    translation = np.degrees(angle_between(est_pose.translation, truth.translation))
    return rotation, float(translation)


DIRECTIONS = [[0, 1, 0], [0, -1, 0], [1, 0, 0], [-1, 0, 0], [0.6, -0.75, 0.28]]


@pytest.mark.parametrize("translation", DIRECTIONS)
def test_noiseless_pairs_give_exact_pose(translation: list[float]) -> None:
    rng = np.random.default_rng(0)
    truth, _, b1, b2 = scene(rng, translation)
    est = estimate_pose(CalibrationPairs(np.arange(len(b1)), b1, b2))
    rotation, direction = errors_deg(est.pose, truth)
    assert rotation < 1e-4 and direction < 1e-4
    assert est.n_inliers == est.n_pairs == len(b1)
    assert est.stats["median_deg"] < 1e-4


@pytest.mark.parametrize("translation", DIRECTIONS)
def test_noisy_pairs_with_outliers(translation: list[float]) -> None:
    rng = np.random.default_rng(1)
    truth, _, b1, b2 = scene(rng, translation)
    b1, b2 = jitter(rng, b1, 0.1), jitter(rng, b2, 0.1)
    # 30 % of the single-flash frames pair two different fireflies.
    swapped = rng.permutation(len(b1))[: int(0.3 * len(b1))]
    b2[swapped] = b2[np.roll(swapped, 1)]
    est = estimate_pose(CalibrationPairs(np.arange(len(b1)), b1, b2))
    rotation, direction = errors_deg(est.pose, truth)
    assert rotation <= 0.1
    assert direction <= 0.5
    outlier = np.zeros(len(b1), dtype=bool)
    outlier[swapped] = True
    # Nearly all true pairs kept; mismatches rejected unless they happen to fit.
    assert np.mean(est.inliers[~outlier]) > 0.97
    assert np.mean(est.inliers[outlier]) < 0.1
    assert est.stats["median_deg"] < 0.2
    assert est.warnings == ()


def test_noise_without_outliers_meets_targets() -> None:
    rng = np.random.default_rng(2)
    truth, _, b1, b2 = scene(rng, [0, 1, 0])
    est = estimate_pose(CalibrationPairs(np.arange(len(b1)), jitter(rng, b1, 0.1), b2))
    rotation, direction = errors_deg(est.pose, truth)
    assert rotation <= 0.1 and direction <= 0.5


def test_sign_of_translation_from_cheirality() -> None:
    rng = np.random.default_rng(3)
    truth, _, b1, b2 = scene(rng, [0, -1, 0])
    est = estimate_pose(CalibrationPairs(np.arange(len(b1)), b1, b2))
    # Not −t̂: that pose fits the same unsigned gaps but puts the points behind.
    assert est.pose.translation @ truth.translation > 0.999
    assert np.all(est.inliers)


def test_large_rotation_found_from_essential_matrix_start() -> None:
    rng = np.random.default_rng(4)
    truth = Pose(Rotation.from_euler("zyx", [70, 20, -15], degrees=True).as_matrix(), [1, 1, 0])
    points = rng.uniform(-12, 12, (300, 3))
    b1 = points / np.linalg.norm(points, axis=1, keepdims=True)
    c2 = truth.world_to_camera2(points, SEPARATION)
    b2 = c2 / np.linalg.norm(c2, axis=1, keepdims=True)
    start = essential_matrix_pose(b1, b2)
    assert max(errors_deg(start, truth)) < 1e-4
    est = estimate_pose(CalibrationPairs(np.arange(300), jitter(rng, b1, 0.1), b2))
    rotation, direction = errors_deg(est.pose, truth)
    assert rotation <= 0.1 and direction <= 0.5


def test_residuals_are_angular_and_gaps_in_separation_units() -> None:
    rng = np.random.default_rng(5)
    truth, points, b1, b2 = scene(rng, [0, 1, 0], n=60)
    depth = np.linalg.norm(points, axis=1)
    near, far = np.argsort(depth)[:5], np.argsort(depth)[-5:]
    bad = np.r_[near, far]
    # Turn these camera-2 bearings by 2° out of their epipolar planes.
    normal = np.cross(truth.translation, b1[bad]) @ truth.rotation.T
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    b2_bad = b2.copy()
    b2_bad[bad] = np.cos(np.radians(2.0)) * b2[bad] + np.sin(np.radians(2.0)) * normal
    est = estimate_pose(CalibrationPairs(np.arange(60), b1, b2_bad))
    assert not est.inliers[bad].any() and est.inliers.sum() == 50
    # In degrees the misses read about the same near and far: at most the 2° turn, at
    # least the RSS split of it over both bearings, less near the cameras.
    assert np.all((est.residuals[bad] > 1.0) & (est.residuals[bad] <= 2.0))
    assert est.residuals[far].min() > 1.3
    # The raw gap (separation units) grows with depth.
    assert np.median(est.gaps[far]) > 4 * np.median(est.gaps[near])
    assert est.stats["p90_gap"] < 1e-6 and est.stats["p90_deg"] < 1e-4


def test_calibration_pairs_use_single_flash_frames_after_delay() -> None:
    rng = np.random.default_rng(6)
    _, _, b1, b2 = scene(rng, [0, 1, 0], n=6)
    u1, v1 = bearing_to_pixel(b1, WIDTH)
    u2, v2 = bearing_to_pixel(b2, WIDTH)
    delay = -3
    # Camera-1 frames 10..15 each hold one flash; frame 12 holds an extra one, and
    # camera 2 misses the flash of frame 14 and has two in frame 15.
    det1 = Detections.from_columns(
        [10, 11, 12, 12, 13, 14, 15], np.r_[u1[:3], 5.0, u1[3:]], np.r_[v1[:3], 5.0, v1[3:]]
    )
    frames2 = np.array([10, 11, 12, 13, 15, 15]) + delay
    det2 = Detections.from_columns(frames2, np.r_[u2[:4], u2[5], 7.0], np.r_[v2[:4], v2[5], 7.0])
    pairs = calibration_pairs(det1, det2, delay, WIDTH)
    np.testing.assert_array_equal(pairs.frame1, [10, 11, 13])
    np.testing.assert_allclose(pairs.bearing1, b1[[0, 1, 3]], atol=1e-12)
    np.testing.assert_allclose(pairs.bearing2, b2[[0, 1, 3]], atol=1e-12)


def test_calibration_pairs_add_frames_where_one_flash_begins() -> None:
    rng = np.random.default_rng(16)
    _, _, b1, b2 = scene(rng, [0, 1, 0], n=5)
    u1, v1 = bearing_to_pixel(b1, WIDTH)
    u2, v2 = bearing_to_pixel(b2, WIDTH)
    # Fireflies 0-4 lit over camera-1 frames: 0 alone in 0, 1 begins in 1 beside it,
    # nothing begins in 2, 2 begins in 3, 3 and 4 begin together in 4. Camera 2 starts
    # recording 2 frames earlier and sees firefly 4 in its frame 0 too.
    lit = {0: range(0, 5), 1: range(1, 4), 2: range(3, 5), 3: [4], 4: [-2, 4]}
    firefly = np.array([f for f, frames in lit.items() for _ in frames])
    frame1 = np.array([k for frames in lit.values() for k in frames])
    delay = 2
    seen1 = frame1 >= 0
    det1 = Detections.from_columns(frame1[seen1], u1[firefly[seen1]], v1[firefly[seen1]])
    det2 = Detections.from_columns(frame1 + delay, u2[firefly], v2[firefly])
    pairs = calibration_pairs(det1, det2, delay, WIDTH, onset_radius_deg=1.0)
    np.testing.assert_array_equal(pairs.frame1, [0, 1, 3])
    np.testing.assert_allclose(pairs.bearing1, b1[[0, 1, 2]], atol=1e-12)
    np.testing.assert_allclose(pairs.bearing2, b2[[0, 1, 2]], atol=1e-12)
    single = calibration_pairs(det1, det2, delay, WIDTH)
    np.testing.assert_array_equal(single.frame1, [0])


def test_too_few_pairs_raise() -> None:
    rng = np.random.default_rng(7)
    _, _, b1, b2 = scene(rng, [0, 1, 0], n=5)
    with pytest.raises(PoseError, match=r"only 5 calibration pairs.*longer recording"):
        estimate_pose(CalibrationPairs(np.arange(5), b1, b2))


def swarm_pairs(seed: int, n: int, mismatched: int) -> tuple[Pose, CalibrationPairs]:
    """Pairs of a swarm (a cone of ~40° near the horizon, 2–20 m; 0.02° of noise) whose
    first `mismatched` pairs join two different fireflies, as a short night gives."""
    rng = np.random.default_rng(seed)
    pose = Pose(Rotation.from_rotvec(np.radians([1.0, -1.0, 2.6])).as_matrix(), [1.0, 0.0, 0.0])
    axis = np.array([0.3, 0.9, 0.1]) / np.linalg.norm([0.3, 0.9, 0.1])
    direction = axis + 0.35 * rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    in_camera2 = pose.world_to_camera2(rng.uniform(2.0, 20.0, (n, 1)) * direction, SEPARATION)
    b1 = jitter(rng, direction, 0.02)
    b2 = jitter(rng, in_camera2 / np.linalg.norm(in_camera2, axis=1, keepdims=True), 0.02)
    b2[:mismatched] = np.roll(b2[:mismatched], 1, axis=0)
    return pose, CalibrationPairs(np.arange(n), b1, b2)


def test_a_few_pairs_of_two_fireflies_do_not_pull_the_pose() -> None:
    # 6 of 40 pairs several degrees off: a loss growing as the residual (soft L1) let
    # them pull the pose 1–10° off on 6 of these 20 swarms.
    for seed in range(20):
        truth, pairs = swarm_pairs(seed, 40, 6)
        est = estimate_pose(pairs)
        assert max(errors_deg(est.pose, truth)) < 0.3, seed
        assert est.n_inliers == 34 and not np.any(est.inliers[:6]), seed


def test_a_quarter_of_mismatched_pairs_do_not_pull_a_near_start() -> None:
    # The graduated fit alone (Cauchy scale from 10° down) let 10 mismatched pairs of 40
    # drag the start R = I, t̂ = x (3° from the truth) 23–92° off, or stop the job, on 6
    # of these 20 swarms; the straight fit at the final scale keeps it in its basin. In a
    # 40° cone a mismatched pair can lie near its epipolar line and pass as an inlier
    # (swarms 1 and 15 keep 2 and 1, and sit 0.4–0.6° off).
    for seed in range(20):
        truth, pairs = swarm_pairs(seed, 40, 10)
        est = estimate_pose(pairs)
        assert max(errors_deg(est.pose, truth)) < 1.0, seed
        assert np.all(est.inliers[10:]) and est.inliers[:10].sum() <= 2, seed


def test_half_mismatched_pairs_warn_and_unrelated_pairs_raise() -> None:
    rng = np.random.default_rng(8)
    truth, _, b1, b2 = scene(rng, [0, 1, 0], n=200)
    mismatched = b2.copy()
    mismatched[90:] = b2[90:][rng.permutation(110)]
    est = estimate_pose(CalibrationPairs(np.arange(200), b1, mismatched))
    assert max(errors_deg(est.pose, truth)) < 0.01
    assert 90 <= est.n_inliers < 100
    assert any("pose inliers" in w for w in est.warnings)
    unrelated = CalibrationPairs(np.arange(200), b1, b2[rng.permutation(200)])
    with pytest.raises(PoseError, match="agree on a pose"):
        estimate_pose(unrelated)


def test_params_validation() -> None:
    with pytest.raises(ValueError, match="exceeds max_threshold_deg"):
        PoseParams(min_threshold_deg=3.0, max_threshold_deg=2.0)


def test_bad_width_raises() -> None:
    det = Detections.from_columns([0], [1.0], [1.0])
    with pytest.raises(ValueError, match="width"):
        calibration_pairs(det, det, 0, 641)


def test_a_pose_that_fits_its_pairs_poorly_is_flagged_against_the_pixel() -> None:
    rng = np.random.default_rng(5)
    _, _, b1, b2 = scene(rng, [0, 1, 0])
    sharp = estimate_pose(CalibrationPairs(np.arange(len(b1)), jitter(rng, b1, 0.03), b2))
    blurred = estimate_pose(CalibrationPairs(np.arange(len(b1)), jitter(rng, b1, 0.4), b2))
    # Median residuals: 0.015° and 0.19°, i.e. 0.03 and 0.34 px at 640 px, and the
    # second only 0.08 px of a 160-px frame's coarser pixels.
    assert fit_warnings(sharp, WIDTH, PoseParams()) == []
    (warning,) = fit_warnings(blurred, WIDTH, PoseParams())
    assert "fits its calibration pairs poorly" in warning
    assert fit_warnings(blurred, 160, PoseParams()) == []


def night_detections(b1: np.ndarray, b2: np.ndarray, snr: np.ndarray) -> tuple[Detections, ...]:
    """One detection per frame and camera at these bearings, with these SNRs."""
    frames = np.arange(len(b1))
    return tuple(
        Detections.from_columns(frames, *bearing_to_pixel(b, WIDTH), snr=snr) for b in (b1, b2)
    )


def faintly_mismatched(
    seed: int, n: int, n_bad: int, random_partners: bool
) -> tuple[Pose, np.ndarray, np.ndarray, np.ndarray]:
    """Bearings of `n` flash pairs (0.02° of noise) whose first `n_bad` pair a spot near
    the confident floor (9 σ) with another pair's flash, or with a random direction;
    the rest are flashes of 20 σ. Returns the pose, both bearings and the SNRs."""
    rng = np.random.default_rng(seed)
    truth, _, b1, b2 = scene(rng, [0, 1, 0], n=n)
    b1, b2 = jitter(rng, b1, 0.02), b2.copy()
    if random_partners:
        b2[:n_bad] = rng.normal(size=(n_bad, 3))
        b2[:n_bad] /= np.linalg.norm(b2[:n_bad], axis=1, keepdims=True)
    else:
        b2[:n_bad] = b2[rng.permutation(n_bad)]
    return truth, b1, b2, np.where(np.arange(n) < n_bad, 9.0, 20.0)


def test_a_pose_pulled_by_faint_artifacts_is_refitted_from_the_bright_flashes() -> None:
    # 60 % of the frames pair a flash with an unrelated spot near the confident floor.
    n_bad = 180
    truth, b1, b2, snr = faintly_mismatched(7, 300, n_bad, random_partners=False)
    det1, det2 = night_detections(b1, b2, snr)

    plain = calibrate_pose(det1, det2, 0, WIDTH, PoseParams(refit_snr=()))
    fit = calibrate_pose(det1, det2, 0, WIDTH)

    assert plain.min_snr is None and plain.warnings
    assert fit.min_snr == 12.0 and fit.warnings == []
    assert fit.estimate.n_pairs == len(b1) - n_bad
    assert [t["min_snr"] for t in fit.tried] == [None, 12.0]
    assert max(errors_deg(fit.estimate.pose, truth)) < 0.05


def test_a_fit_that_fails_outright_is_refitted_from_the_bright_flashes() -> None:
    # A grainy night: most frames pair speckle as confident as a flash (near the floor)
    # with an unrelated spot, so too few pairs agree for any fit; the flashes of 20 σ
    # agree (a 4K night, hard-noisy s12: 11 of 66 pairs agreed, 75 of 78 at ≥ 12 σ).
    truth, b1, b2, snr = faintly_mismatched(11, 400, 340, random_partners=True)
    det1, det2 = night_detections(b1, b2, snr)
    with pytest.raises(PoseError, match="agree on a pose"):
        calibrate_pose(det1, det2, 0, WIDTH, PoseParams(refit_snr=()))

    fit = calibrate_pose(det1, det2, 0, WIDTH)
    assert fit.min_snr == 12.0 and fit.warnings == []
    assert "error" in fit.tried[0] and fit.tried[1]["n_inliers"] >= 55
    assert max(errors_deg(fit.estimate.pose, truth)) < 0.05

    hopeless = night_detections(b1, b2[np.random.default_rng(0).permutation(len(b2))], snr)
    with pytest.raises(PoseError, match="nor from the flashes of at least 12, 16, 24 σ"):
        calibrate_pose(*hopeless, 0, WIDTH)


def test_a_clean_night_keeps_every_flash_and_a_hopeless_one_keeps_its_best_fit() -> None:
    rng = np.random.default_rng(8)
    _, _, b1, b2 = scene(rng, [0, 1, 0], n=300)
    det1, det2 = night_detections(jitter(rng, b1, 0.02), b2, np.full(len(b1), 9.0))
    clean = calibrate_pose(det1, det2, 0, WIDTH)
    assert clean.min_snr is None and clean.warnings == [] and len(clean.tried) == 1

    blurred = night_detections(jitter(rng, b1, 0.4), b2, rng.uniform(8.0, 30.0, len(b1)))
    poor = calibrate_pose(*blurred, 0, WIDTH)
    assert any("fits its calibration pairs poorly" in w for w in poor.warnings)
    assert len(poor.tried) == 4  # every floor tried, none fits well
    # Each warns alike, so the fit its pairs determine best is kept (all 300 pairs), not
    # the one whose fewer bright pairs happen to fit closest.
    residuals = [t["median_residual_px"] for t in poor.tried]
    assert poor.min_snr is None and residuals[0] > min(residuals)


def horizon_scene(
    rng: np.random.Generator, n: int, elevation_deg: float
) -> tuple[Pose, np.ndarray, np.ndarray]:
    """Points 2–15 m away within ``elevation_deg`` of the horizon, side-by-side cameras."""
    pose = Pose(Rotation.from_rotvec(np.radians([0.5, -0.8, 4.0])).as_matrix(), [0, 1, 0])
    azimuth = rng.uniform(0, 2 * np.pi, n)
    elevation = np.radians(rng.uniform(-elevation_deg, elevation_deg, n))
    direction = np.column_stack(
        [
            np.cos(elevation) * np.cos(azimuth),
            np.cos(elevation) * np.sin(azimuth),
            np.sin(elevation),
        ]
    )
    in_camera2 = pose.world_to_camera2(rng.uniform(2.0, 15.0, (n, 1)) * direction, SEPARATION)
    return pose, direction, in_camera2 / np.linalg.norm(in_camera2, axis=1, keepdims=True)


def test_standard_errors_predict_the_errors_and_flag_weak_geometry() -> None:
    rng = np.random.default_rng(9)
    errors, standard_errors = [], []
    for _ in range(40):
        truth, b1, b2 = horizon_scene(rng, 20, elevation_deg=2.0)
        est = estimate_pose(CalibrationPairs(np.arange(20), jitter(rng, b1, 0.05), b2))
        errors.append(errors_deg(est.pose, truth))
        standard_errors.append((est.stats["rotation_se_deg"], est.stats["translation_se_deg"]))
    # Each error's root mean square is about its predicted standard error (the worst
    # axis' error bounds the total from above, the other axes add to it).
    ratio = np.sqrt(np.mean(np.square(errors), axis=0)) / np.median(standard_errors, axis=0)
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio
    # Few pairs hugging the horizon leave the rotation loose; pairs all round do not.
    _, b1, b2 = horizon_scene(rng, 15, elevation_deg=0.5)
    loose = estimate_pose(CalibrationPairs(np.arange(15), jitter(rng, b1, 0.05), b2))
    _, _, b1, b2 = scene(rng, [0, 1, 0], n=300)
    firm = estimate_pose(CalibrationPairs(np.arange(300), jitter(rng, b1, 0.05), b2))
    assert firm.stats["rotation_se_deg"] < 0.05 < 0.3 < loose.stats["rotation_se_deg"]
    assert firm.stats["translation_se_deg"] < loose.stats["translation_se_deg"]
    (warning,) = fit_warnings(loose, WIDTH, PoseParams())
    assert "poorly determined" in warning
    assert fit_warnings(firm, WIDTH, PoseParams()) == []


def flashes_of_a_night(
    rng: np.random.Generator, n_flashes: int, frames: int, misplaced_deg: float
) -> tuple[Pose, CalibrationPairs]:
    """Pairs of `n_flashes` flashes lit `frames` frames each, in frame order; each flash
    misplaced in camera 1 by its own `misplaced_deg` (a spot on a swaying edge) plus
    0.02° of grain a frame."""
    truth, direction, b2 = horizon_scene(rng, n_flashes, elevation_deg=10.0)
    shared = np.repeat(jitter(rng, direction, misplaced_deg), frames, axis=0)
    b1 = jitter(rng, shared, 0.02)
    return truth, CalibrationPairs(np.arange(len(b1)), b1, np.repeat(b2, frames, axis=0))


def test_the_jackknife_sees_errors_a_flash_shares_across_its_frames() -> None:
    rng = np.random.default_rng(3)
    errors, jacobian, jackknife = [], [], []
    for _ in range(40):
        truth, pairs = flashes_of_a_night(rng, 25, 5, misplaced_deg=0.15)
        est = estimate_pose(pairs)
        errors.append(errors_deg(est.pose, truth)[0])
        jacobian.append(est.stats["rotation_se_deg"])
        jackknife.append(est.stats["rotation_jackknife_se_deg"])
    rms = np.sqrt(np.mean(np.square(errors)))
    # The Jacobian takes the 125 pairs as independent and promises a third of the error;
    # leaving out whole stretches of the night measures it.
    assert rms / np.median(jacobian) > 2.5
    assert 0.5 < rms / np.median(jackknife) < 2.0
    # A night whose few flashes are each misplaced by a pixel of a 640 px frame: the
    # Jacobian alone would pass it, the jackknife flags it.
    _, pairs = flashes_of_a_night(np.random.default_rng(5), 12, 10, misplaced_deg=0.5)
    loose = estimate_pose(pairs)
    assert loose.stats["rotation_se_deg"] < 0.3 < loose.stats["rotation_jackknife_se_deg"]
    assert any("poorly determined" in w for w in fit_warnings(loose, WIDTH, PoseParams()))
    # Too few pairs to leave blocks out: no jackknife, and the Jacobian decides alone.
    _, b1, b2 = horizon_scene(rng, 15, elevation_deg=2.0)
    few = estimate_pose(CalibrationPairs(np.arange(15), jitter(rng, b1, 0.05), b2))
    assert np.isnan(few.stats["rotation_jackknife_se_deg"])


def test_the_worst_axis_covariance_spreads_each_part_evenly() -> None:
    rng = np.random.default_rng(2)
    _, b1, b2 = horizon_scene(rng, 30, elevation_deg=3.0)
    est = estimate_pose(CalibrationPairs(np.arange(30), jitter(rng, b1, 0.05), b2))
    spread = worst_axis_covariance(est.covariance, est.pose.translation)
    rotation_se, translation_se = standard_errors_deg(est.covariance)
    np.testing.assert_allclose(np.diag(spread)[:3], np.radians(rotation_se) ** 2)
    # Every direction across the baseline gets its worst variance, none along it.
    np.testing.assert_allclose(
        np.linalg.eigvalsh(spread[3:, 3:]),
        [0.0, *[np.radians(translation_se) ** 2] * 2],
        atol=1e-15,
    )
    np.testing.assert_allclose(spread[3:, 3:] @ est.pose.translation, 0.0, atol=1e-15)
    assert not spread[:3, 3:].any()
    # Each part is at least as uncertain in every direction as the fit says it is.
    for part in (slice(0, 3), slice(3, 6)):
        assert np.linalg.eigvalsh(spread[part, part] - est.covariance[part, part]).min() > -1e-15
    assert np.isinf(worst_axis_covariance(np.full((6, 6), np.inf), est.pose.translation)).all()


def cone_scene(
    rng: np.random.Generator, n: int, spread_deg: float
) -> tuple[Pose, np.ndarray, np.ndarray]:
    """Exact bearings of `n` points 3–6 m away within about `spread_deg` of one direction
    at right angles to the baseline (a swarm)."""
    pose = Pose(Rotation.from_rotvec(np.radians([1.0, -2.0, 3.0])).as_matrix(), [1.0, 0.0, 0.0])
    direction = np.array([0.0, 1.0, 0.0]) + np.radians(spread_deg) * rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    in_camera2 = pose.world_to_camera2(rng.uniform(3.0, 6.0, (n, 1)) * direction, SEPARATION)
    return pose, direction, in_camera2 / np.linalg.norm(in_camera2, axis=1, keepdims=True)


def test_a_swarm_seen_in_a_narrow_cone_leaves_the_baseline_loose() -> None:
    rng = np.random.default_rng(4)
    fits, off = {}, {}
    for spread in (5.0, 30.0):
        truth, b1, b2 = cone_scene(rng, 200, spread)
        pairs = CalibrationPairs(np.arange(200), jitter(rng, b1, 0.05), jitter(rng, b2, 0.05))
        fits[spread] = estimate_pose(pairs)
        off[spread] = errors_deg(fits[spread].pose, truth)[1]
    narrow, wide = fits[5.0], fits[30.0]
    # Rotation and baseline trade off under a narrow cone: the same grain leaves the
    # baseline's direction loose, and the standard error says so.
    assert translation_se_deg(wide) < 0.1 < 0.5 < translation_se_deg(narrow)
    assert off[30.0] < 0.2 < off[5.0]
    (warning,) = baseline_warnings(narrow, PoseParams())
    assert "baseline's direction is poorly determined" in warning
    assert baseline_warnings(wide, PoseParams()) == []
    assert baseline_warnings(narrow, PoseParams(max_translation_se_deg=5.0)) == []


def test_the_baseline_error_is_scaled_like_the_rotation_by_the_jackknife() -> None:
    _, pairs = flashes_of_a_night(np.random.default_rng(5), 12, 10, misplaced_deg=0.5)
    est = estimate_pose(pairs)
    ratio = rotation_se_deg(est) / est.stats["rotation_se_deg"]
    assert ratio > 2.0  # the jackknife sees the flashes' shared errors
    assert translation_se_deg(est) == pytest.approx(est.stats["translation_se_deg"] * ratio)
