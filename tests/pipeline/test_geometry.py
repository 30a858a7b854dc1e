import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.geometry import (
    Pose,
    angle_between,
    bearing_to_pixel,
    closest_approach,
    pixel_to_bearing,
    rotation_angle,
)

W = 640


def test_contract_axes() -> None:
    # Row 0 is the zenith, the middle row is the horizon, u = 0 looks along +x.
    np.testing.assert_allclose(pixel_to_bearing(0, 0, W), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(pixel_to_bearing(0, W / 4, W), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(pixel_to_bearing(W / 4, W / 4, W), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(pixel_to_bearing(W / 2, W / 4, W), [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(pixel_to_bearing(0, W / 2, W), [0, 0, -1], atol=1e-12)


def test_round_trip_including_seam() -> None:
    rng = np.random.default_rng(0)
    u = np.concatenate([rng.uniform(0, W, 1000), [0.0, 1e-9, W - 1e-9, W - 0.5]])
    v = np.concatenate([rng.uniform(1, W / 2 - 1, 1000), [10.0, 20.0, 30.0, 40.0]])
    u2, v2 = bearing_to_pixel(pixel_to_bearing(u, v, W), W)
    du = np.abs((u2 - u + W / 2) % W - W / 2)  # circular difference across the seam
    assert du.max() < 1e-6
    np.testing.assert_allclose(v2, v, atol=1e-9)
    assert np.all((u2 >= 0) & (u2 < W))


def test_u_wraps() -> None:
    np.testing.assert_allclose(
        pixel_to_bearing(-0.25, 50, W), pixel_to_bearing(W - 0.25, 50, W), atol=1e-12
    )


def _random_pose(rng: np.random.Generator) -> Pose:
    return Pose(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))


def test_closest_approach_matches_lstsq() -> None:
    rng = np.random.default_rng(1)
    pose = _random_pose(rng)
    a = rng.normal(size=(50, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b2 = rng.normal(size=(50, 3))
    b2 /= np.linalg.norm(b2, axis=1, keepdims=True)
    pair = closest_approach(a, b2, pose)
    b = b2 @ pose.rotation
    for i in range(50):
        # r1 a - r2 b = t in the least-squares sense.
        sol, *_ = np.linalg.lstsq(np.stack([a[i], -b[i]], axis=1), pose.translation, rcond=None)
        np.testing.assert_allclose([pair.r1[i], pair.r2[i]], sol, atol=1e-9)
        p1, p2 = sol[0] * a[i], pose.translation + sol[1] * b[i]
        assert pair.gap[i] == pytest.approx(np.linalg.norm(p1 - p2), abs=1e-9)
        np.testing.assert_allclose(pair.midpoint[i], (p1 + p2) / 2, atol=1e-9)


def test_closest_approach_recovers_noiseless_point() -> None:
    rng = np.random.default_rng(2)
    pose = _random_pose(rng)
    separation = 1.7
    x = rng.uniform(-10, 10, size=(200, 3))
    a1 = x / np.linalg.norm(x, axis=1, keepdims=True)
    c2 = pose.world_to_camera2(x, separation)
    a2 = c2 / np.linalg.norm(c2, axis=1, keepdims=True)
    pair = closest_approach(a1, a2, pose)
    np.testing.assert_allclose(pair.gap, 0, atol=1e-9)
    np.testing.assert_allclose(pair.midpoint * separation, x, atol=1e-7)
    np.testing.assert_allclose(pair.r1 * separation, np.linalg.norm(x, axis=1), atol=1e-7)


def test_nonnegative_depths_brute_force() -> None:
    rng = np.random.default_rng(3)
    pose = _random_pose(rng)
    a = rng.normal(size=(300, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b2 = rng.normal(size=(300, 3))
    b2 /= np.linalg.norm(b2, axis=1, keepdims=True)
    pair = closest_approach(a, b2, pose, nonnegative=True)
    assert np.all(pair.r1 >= 0) and np.all(pair.r2 >= 0)
    b = b2 @ pose.rotation
    grid = np.linspace(0, 6, 301)
    r1g, r2g = np.meshgrid(grid, grid, indexing="ij")
    for i in range(0, 300, 15):
        gaps = np.linalg.norm(
            r1g[..., None] * a[i] - pose.translation - r2g[..., None] * b[i], axis=-1
        )
        assert pair.gap[i] <= gaps.min() + 1e-9


def test_rotation_and_vector_angles() -> None:
    r = Rotation.from_euler("z", 0.3, degrees=True).as_matrix()
    assert np.degrees(rotation_angle(r, np.eye(3))) == pytest.approx(0.3, abs=1e-9)
    assert angle_between([1, 0, 0], [0, 1, 0]) == pytest.approx(np.pi / 2)


def test_pose_normalises_translation() -> None:
    pose = Pose(np.eye(3), [0, 2, 0])
    np.testing.assert_allclose(pose.translation, [0, 1, 0])
    with pytest.raises(ValueError):
        Pose(np.eye(3), [0, 0, 0])
