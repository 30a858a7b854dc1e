import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import pipeline.triangulate
from pipeline.detections import Detections
from pipeline.geometry import Pose, bearing_to_pixel, closest_approach
from pipeline.params import TriangulationParams, validate_separation
from pipeline.results import Calibration, read_calibration, write_calibration
from pipeline.triangulate import (
    Points3D,
    candidate_pairs,
    frame_batches,
    localisation_rad,
    parallax,
    range_sd,
    triangulate,
)

WIDTH = 640
SEPARATION = 1.5
POSE = Pose(Rotation.from_rotvec(np.radians([0.5, -1.0, 2.0])).as_matrix(), [0.1, 1.0, 0.02])
# Noise-free points anywhere around the rig: some lie near the baseline axis, where the
# default parallax cut (for real, noisy detections) would drop them.
EXACT = TriangulationParams(min_parallax_px=0.0)


def detections_of(points: np.ndarray, frames: np.ndarray, camera: int) -> Detections:
    """Exact detections of world points (metres) by camera 1 or camera 2."""
    seen = points if camera == 1 else POSE.world_to_camera2(points, SEPARATION)
    u, v = bearing_to_pixel(seen, WIDTH)
    return Detections.from_columns(frames, u, v)


def random_points(rng: np.random.Generator, n: int, near: float = 2.0, far: float = 15.0):
    direction = rng.normal(size=(n, 3))
    direction[:, 2] = np.abs(direction[:, 2])  # above the horizon, like fireflies in view
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return rng.uniform(near, far, (n, 1)) * direction


def test_exact_points_recovered_at_scale() -> None:
    rng = np.random.default_rng(0)
    points = random_points(rng, 300)
    frames = np.arange(300)
    result = triangulate(
        detections_of(points, frames, 1),
        detections_of(points, frames, 2),
        0,
        POSE,
        WIDTH,
        SEPARATION,
        EXACT,
    )
    assert len(result) == 300
    np.testing.assert_array_equal(result.index1, result.index2)
    np.testing.assert_allclose(result.xyz, points[result.index1], atol=1e-6)
    np.testing.assert_allclose(result.range_m, np.linalg.norm(result.xyz, axis=1))
    assert result.gap_m.max() < 1e-6
    np.testing.assert_array_equal(result.frame, frames)


def test_several_flashes_per_frame_matched_with_negative_delay() -> None:
    rng = np.random.default_rng(1)
    n_frames, per_frame, delay = 200, 4, -7
    frames = np.repeat(np.arange(n_frames), per_frame)
    points = random_points(rng, len(frames))
    det1 = detections_of(points, frames, 1)
    # Camera 2 lists its detections in another order; frames before its start are lost.
    shuffle = rng.permutation(len(frames))
    shuffle = shuffle[frames[shuffle] + delay >= 0]
    det2 = detections_of(points[shuffle], frames[shuffle] + delay, 2)
    result = triangulate(det1, det2, delay, POSE, WIDTH, SEPARATION, EXACT)
    # Row j of camera 2 shows world point shuffle[j].
    np.testing.assert_array_equal(shuffle[result.index2], result.index1)
    # Every flash of every frame both cameras saw, and only those.
    assert len(result) == np.sum(frames + delay >= 0)
    assert result.frame.min() == -delay
    assert np.all(np.diff(result.frame) >= 0)
    np.testing.assert_allclose(result.xyz, points[result.index1], atol=1e-6)


def test_crowded_frames_are_matched_in_batches_with_the_same_result(monkeypatch) -> None:
    """Many candidates a frame, shuffled, with frames seen by one camera only and a
    delay: batches of a few frames give the points of one pass, row for row."""
    rng = np.random.default_rng(7)
    frames = np.repeat(np.arange(60), rng.integers(1, 12, 60))
    points = random_points(rng, len(frames))
    det1 = detections_of(points, frames, 1)
    shuffle = rng.permutation(len(frames))[: len(frames) - 40]
    noisy = detections_of(points[shuffle], frames[shuffle] + 3, 2)
    det2 = Detections.from_columns(
        np.r_[noisy.frame, [100, 101]],
        np.r_[noisy.x + rng.normal(0, 0.3, len(noisy)), [10.0, 20.0]],
        np.r_[noisy.y, [100.0, 120.0]],
    )
    whole = triangulate(det1, det2, 3, POSE, WIDTH, SEPARATION)
    monkeypatch.setattr(pipeline.triangulate, "MAX_PAIRS", 50)
    assert len(frame_batches(det1.frame, det2.frame - 3, 50)) > 10
    batched = triangulate(det1, det2, 3, POSE, WIDTH, SEPARATION)
    assert len(whole) > 100
    for name in ("xyz", "frame", "gap_m", "range_m", "range_sd_m", "index1", "index2"):
        np.testing.assert_array_equal(getattr(batched, name), getattr(whole, name))


def test_frame_batches_hold_whole_frames_and_bounded_pairs() -> None:
    frame1 = np.array([5, 0, 0, 1, 1, 1, 2, 7, 9])
    frame2 = np.array([0, 1, 1, 2, 2, 2, 2, 7, 8])
    batches = frame_batches(frame1, frame2, 4)
    # Pairs per shared frame: 0: 2, 1: 6, 2: 4, 7: 1. Every row in exactly one batch.
    assert sorted(np.concatenate([b[0] for b in batches]).tolist()) == list(range(9))
    assert sorted(np.concatenate([b[1] for b in batches]).tolist()) == list(range(9))
    assert [sorted(set(frame1[b[0]]) & set(frame2[b[1]])) for b in batches] == [[0, 1], [2], [7]]
    for rows1, rows2 in batches:
        shared = sorted(set(frame1[rows1]) & set(frame2[rows2]))
        pairs = [np.sum(frame1[rows1] == f) * np.sum(frame2[rows2] == f) for f in shared]
        assert sum(pairs[:-1]) < 4  # under the bound, but for the batch's last frame
    whole = frame_batches(frame1, frame2, 13)
    assert len(whole) == 1 and len(whole[0][0]) == 9


def test_frames_seen_by_one_camera_only_yield_nothing() -> None:
    rng = np.random.default_rng(2)
    points = random_points(rng, 6)
    det1 = detections_of(points, np.array([0, 1, 2, 3, 4, 5]), 1)
    det2 = detections_of(points[[0, 2, 5]], np.array([0, 2, 5]), 2)
    result = triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION)
    np.testing.assert_array_equal(result.frame, [0, 2, 5])
    np.testing.assert_array_equal(result.index1, [0, 2, 5])
    np.testing.assert_array_equal(result.index2, [0, 1, 2])


def test_gate_refuses_rays_that_miss() -> None:
    rng = np.random.default_rng(3)
    points = random_points(rng, 2, near=4.0, far=6.0)
    det1 = detections_of(points, np.array([0, 1]), 1)
    # Camera 2 sees in frame 1 a flash moved 0.5 m (1/3 separation) out of its epipolar
    # plane, plus an extra flash of its own in frame 0 that must not steal the true match.
    shifted = points.copy()
    normal = np.cross(POSE.translation, points[1])
    shifted[1] += 0.5 * normal / np.linalg.norm(normal)
    extra = points[0] + [0.0, 0.0, 2.0]
    det2 = detections_of(np.vstack([extra, points[0], shifted[1]]), np.array([0, 0, 1]), 2)
    result = triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION)
    np.testing.assert_array_equal(result.index2, [1])
    loose_params = TriangulationParams(gate=0.5, max_gap_deg=20.0)
    loose = triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION, loose_params)
    np.testing.assert_array_equal(loose.index2, [1, 2])
    assert 0.2 * SEPARATION < loose.gap_m[1] < 0.5 * SEPARATION


def test_max_range_and_points_behind_cameras_are_dropped() -> None:
    rng = np.random.default_rng(4)
    near = random_points(rng, 3, near=3.0, far=10.0)
    far = random_points(rng, 2, near=25.0, far=30.0)
    points = np.vstack([near, far])
    frames = np.arange(5)
    det1 = detections_of(points, frames, 1)
    det2 = detections_of(points, frames, 2)
    result = triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION)
    np.testing.assert_array_equal(result.index1, [0, 1, 2])
    wide = triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION, TriangulationParams(max_range_m=40))
    np.testing.assert_array_equal(wide.index1, [0, 1, 2, 3, 4])
    # Rays that meet only behind both cameras: camera 1 looks away from the point.
    behind = Detections.from_columns([0], *bearing_to_pixel(-near[:1], WIDTH))
    away = POSE.world_to_camera2(near[:1], SEPARATION)
    behind2 = Detections.from_columns([0], *bearing_to_pixel(-away, WIDTH))
    assert len(triangulate(behind, behind2, 0, POSE, WIDTH, SEPARATION)) == 0


def test_angular_gate_refuses_near_mismatches_the_gate_allows() -> None:
    # 40 cm from camera 1, a flash moved 10 cm (1/15 separation, well inside the 0.2
    # gate) out of its epipolar plane: a ~14 degree inconsistency, not a match.
    point = np.array([[0.4, 0.0, 0.1]])
    normal = np.cross(POSE.translation, point[0])
    shifted = point + 0.1 * normal / np.linalg.norm(normal)
    det1 = detections_of(point, np.array([0]), 1)
    det2 = detections_of(shifted, np.array([0]), 2)
    assert len(triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION)) == 0
    lenient = TriangulationParams(max_gap_deg=30.0)
    (gap,) = triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION, lenient).gap_m
    assert gap < 0.2 * SEPARATION


def test_points_near_the_baseline_axis_are_dropped() -> None:
    # Along the baseline the two rays are nearly parallel: depth is unobservable.
    axis = POSE.translation / np.linalg.norm(POSE.translation)
    on_axis = 8.0 * axis + [0.0, 0.0, 0.05]
    broadside = 8.0 * np.cross(axis, [0.0, 0.0, 1.0]) + [0.0, 0.0, 1.0]
    points = np.vstack([on_axis, broadside])
    frames = np.arange(2)
    det1, det2 = detections_of(points, frames, 1), detections_of(points, frames, 2)
    np.testing.assert_array_equal(triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION).index1, [1])
    keep_all = TriangulationParams(min_parallax_px=0.0)
    np.testing.assert_array_equal(
        triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION, keep_all).index1, [0, 1]
    )


def test_parallax_is_the_angle_the_baseline_subtends() -> None:
    pose = Pose(np.eye(3), [0.0, 1.0, 0.0])
    distance = np.array([0.5, 2.0, 10.0])
    broadside = np.column_stack([distance, np.full(3, 0.5), np.zeros(3)])
    np.testing.assert_allclose(parallax(broadside, pose), 2 * np.arctan(0.5 / distance))
    np.testing.assert_allclose(parallax(np.array([[0.0, 5.0, 0.0]]), pose), [0.0], atol=1e-12)


def test_candidate_pairs_blocks() -> None:
    pairs = candidate_pairs(np.array([5, 3, 5, 9]), np.array([5, 5, 3, 7, 5]))
    np.testing.assert_array_equal(pairs.frame, [3, 5])
    np.testing.assert_array_equal(pairs.n1, [1, 2])
    np.testing.assert_array_equal(pairs.n2, [1, 3])
    np.testing.assert_array_equal(pairs.start, [0, 1])
    np.testing.assert_array_equal(pairs.index1, [1, 0, 0, 0, 2, 2, 2])
    np.testing.assert_array_equal(pairs.index2, [2, 0, 1, 4, 0, 1, 4])


def test_empty_inputs_and_select() -> None:
    det = Detections.empty()
    result = triangulate(det, det, 0, POSE, WIDTH, SEPARATION)
    assert len(result) == 0 and result.xyz.shape == (0, 3)
    rng = np.random.default_rng(5)
    points = random_points(rng, 4)
    full = triangulate(
        detections_of(points, np.arange(4), 1),
        detections_of(points, np.arange(4), 2),
        0,
        POSE,
        WIDTH,
        SEPARATION,
    )
    part = full.select(full.range_m > np.median(full.range_m))
    assert isinstance(part, Points3D) and len(part) == 2
    np.testing.assert_allclose(part.xyz, points[part.index1], atol=1e-6)


@pytest.mark.parametrize("separation", [0.0, -1.5, float("nan"), float("inf"), 150.0])
def test_absurd_separation_refused(separation: float) -> None:
    with pytest.raises(ValueError, match="camera separation"):
        validate_separation(separation)
    det = Detections.empty()
    with pytest.raises(ValueError, match="camera separation"):
        triangulate(det, det, 0, POSE, WIDTH, separation)


def test_assignment_with_several_flashes_respects_gate() -> None:
    rng = np.random.default_rng(6)
    a, b, c = random_points(rng, 3, near=3.0, far=12.0)
    # Both cameras see two flashes in frame 4, but only A is common; B and C are each
    # seen by one camera (occlusion), so B–C must stay unmatched.
    det1 = detections_of(np.array([b, a]), np.array([4, 4]), 1)
    det2 = detections_of(np.array([a, c]), np.array([4, 4]), 2)
    result = triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION)
    np.testing.assert_array_equal(result.index1, [1])
    np.testing.assert_array_equal(result.index2, [0])
    np.testing.assert_allclose(result.xyz, [a], atol=1e-6)


def _jittered(bearing: np.ndarray, sd: float, rng: np.random.Generator) -> np.ndarray:
    """The bearing turned by an isotropic angular error of `sd` radians."""
    moved = bearing + rng.normal(0.0, sd, bearing.shape)
    moved -= np.sum(moved * bearing, axis=-1, keepdims=True) * bearing - bearing
    return moved / np.linalg.norm(moved, axis=-1, keepdims=True)


def test_range_sd_predicts_the_scatter_of_noisy_triangulations() -> None:
    rng = np.random.default_rng(3)
    points = random_points(rng, 6, near=3.0, far=18.0) / SEPARATION  # baseline units
    b1 = points / np.linalg.norm(points, axis=1, keepdims=True)
    in2 = POSE.world_to_camera2(points, 1.0)
    b2 = in2 / np.linalg.norm(in2, axis=1, keepdims=True)
    sd1, sd2 = np.full(6, 2e-3), np.full(6, 1e-3)
    predicted = range_sd(b1, b2, POSE, sd1, sd2)
    draws = np.stack(
        [
            np.linalg.norm(
                closest_approach(_jittered(b1, 2e-3, rng), _jittered(b2, 1e-3, rng), POSE).midpoint,
                axis=-1,
            )
            for _ in range(4000)
        ]
    )
    np.testing.assert_allclose(draws.std(axis=0), predicted, rtol=0.08)


def test_points_carry_a_range_sd_that_grows_with_range_and_falls_with_snr() -> None:
    direction = np.array([1.0, -0.1, 0.3]) / np.linalg.norm([1.0, -0.1, 0.3])  # ⟂ baseline
    points = np.outer([4.0, 8.0, 16.0, 16.0], direction)
    frames = np.arange(4)
    det1, det2 = detections_of(points, frames, 1), detections_of(points, frames, 2)
    snr = np.array([9.0, 9.0, 9.0, 36.0])
    det1 = Detections.from_columns(frames, det1.x, det1.y, snr=snr)
    det2 = Detections.from_columns(frames, det2.x, det2.y, snr=snr)
    sd = triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION, EXACT).range_sd_m
    assert sd[0] < sd[1] < sd[2]
    np.testing.assert_allclose(sd[2] / sd[1], 4.0, rtol=0.1)  # far away: r² along a ray
    np.testing.assert_allclose(sd[3] / sd[2], 0.5, rtol=1e-6)  # σ ∝ 1 / √SNR
    assert 0.1 < sd[2] < 2.0  # metres at 16 m, 640 px, 1.5 m apart
    covariance = np.diag([4e-6, 4e-6, 4e-6, 1e-6, 1e-6, 1e-6])  # 2 mrad on each rotation axis
    posed = triangulate(det1, det2, 0, POSE, WIDTH, SEPARATION, EXACT, pose_covariance=covariance)
    assert np.all(posed.range_sd_m > sd)  # the pose's own error adds to the detections'
    # ... in variance, by the square of `pose_error_scale`; 0 leaves it out.
    variances = [
        triangulate(
            det1,
            det2,
            0,
            POSE,
            WIDTH,
            SEPARATION,
            EXACT.model_copy(update={"pose_error_scale": scale}),
            pose_covariance=covariance,
        ).range_sd_m
        ** 2
        for scale in (0.0, 1.0, 2.0)
    ]
    np.testing.assert_allclose(variances[0], sd**2)
    np.testing.assert_allclose(variances[2] - variances[0], 4 * (variances[1] - variances[0]))


def pose_draw(rng: np.random.Generator, covariance: np.ndarray) -> Pose:
    """A pose drawn about `POSE` from a covariance of its six parameters."""
    omega_t = rng.multivariate_normal(np.zeros(6), covariance)
    turn = Rotation.from_rotvec(omega_t[:3]).as_matrix()
    return Pose(turn @ POSE.rotation, POSE.translation + omega_t[3:])


def test_range_sd_predicts_the_scatter_from_the_pose_error() -> None:
    rng = np.random.default_rng(4)
    points = random_points(rng, 6, near=3.0, far=18.0) / SEPARATION
    b1 = points / np.linalg.norm(points, axis=1, keepdims=True)
    in2 = POSE.world_to_camera2(points, 1.0)
    b2 = in2 / np.linalg.norm(in2, axis=1, keepdims=True)
    # The baseline's direction loose in one plane, the rotation mildly, the two coupled;
    # nothing along the (unit) translation itself.
    t = POSE.translation
    across = np.cross(t, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    mixing = np.zeros((6, 6))
    mixing[:3, :3] = 1e-3 * np.eye(3)
    mixing[3:, 3] = 4e-3 * across
    mixing[3:, 0] = 1e-3 * np.cross(t, across)
    covariance = mixing @ mixing.T
    zero = np.zeros(6)
    predicted = range_sd(b1, b2, POSE, zero, zero, covariance)
    draws = np.stack(
        [
            np.linalg.norm(closest_approach(b1, b2, pose_draw(rng, covariance)).midpoint, axis=-1)
            for _ in range(4000)
        ]
    )
    np.testing.assert_allclose(draws.std(axis=0), predicted, rtol=0.08)
    undetermined = np.full((6, 6), np.inf)
    assert np.isinf(range_sd(b1, b2, POSE, zero, zero, undetermined)).all()


def test_calibration_carries_the_pose_covariance(tmp_path) -> None:
    covariance = np.diag([1e-6, 2e-6, 3e-6, 4e-6, 0.0, 5e-6])
    calibration = Calibration(0, 1.0, POSE, SEPARATION, 30.0, WIDTH, WIDTH // 2)
    posed = Calibration(0, 1.0, POSE, SEPARATION, 30.0, WIDTH, WIDTH // 2, 0.1, covariance)
    write_calibration(tmp_path / "with.json", posed, {"residuals": {"rotation_se_deg": 0.1}})
    back = read_calibration(tmp_path / "with.json")
    np.testing.assert_array_equal(back.pose_covariance, covariance)
    # An earlier release's calibration: its rotation standard error on every axis.
    write_calibration(tmp_path / "older.json", calibration, {"residuals": {"rotation_se_deg": 0.2}})
    older = read_calibration(tmp_path / "older.json")
    assert older.covariance is None and older.rotation_se_deg == 0.2
    np.testing.assert_allclose(np.diag(older.pose_covariance)[:3], np.radians(0.2) ** 2)
    assert not older.pose_covariance[3:].any()
    write_calibration(tmp_path / "without.json", calibration, {})
    assert not read_calibration(tmp_path / "without.json").pose_covariance.any()
    # An undetermined pose (too few pairs) is written as nulls and read back as NaN.
    loose = Calibration(
        0, 1.0, POSE, SEPARATION, 30.0, WIDTH, WIDTH // 2, 0.0, np.full((6, 6), np.inf)
    )
    write_calibration(tmp_path / "loose.json", loose, {})
    assert np.isnan(read_calibration(tmp_path / "loose.json").pose_covariance).all()


def test_localisation_follows_the_square_root_of_snr_and_tolerates_no_snr() -> None:
    sd = localisation_rad(np.array([4.0, 16.0, np.nan]), 640, 0.5)
    px = sd * 640 / (2 * np.pi)
    np.testing.assert_allclose(px[:2], [0.25, 0.125])
    assert np.isfinite(px[2])
