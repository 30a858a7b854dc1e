"""The running tile estimate of the foreground's noise (pipeline.noise)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.noise import TileNoise, negative_side_sigma, tile_grid


def test_a_known_sigma_is_recovered_per_tile() -> None:
    rng = np.random.default_rng(0)
    sigma = np.array([[0.5, 1.0, 2.0, 4.0]], np.float32)  # one row of four tiles
    noise = TileNoise((1, 4), window=30)
    for _ in range(30):
        frame = rng.normal(0, 1, (32, 128)).astype(np.float32) * np.repeat(sigma, 32, axis=1)
        noise.update(frame)
    assert noise.frames == 30
    np.testing.assert_allclose(noise.sigma(), sigma, rtol=0.03)


def test_flashes_do_not_inflate_the_estimate() -> None:
    rng = np.random.default_rng(1)
    quiet, lit = TileNoise((2, 2), window=20), TileNoise((2, 2), window=20)
    for _ in range(20):
        frame = rng.normal(0, 1.5, (64, 64)).astype(np.float32)
        flashed = frame.copy()
        flashed[rng.integers(0, 64, 40), rng.integers(0, 64, 40)] += 200.0  # 40 bright spots
        quiet.update(frame)
        lit.update(flashed)
    np.testing.assert_allclose(lit.sigma(), quiet.sigma(), rtol=0.02)
    np.testing.assert_allclose(quiet.sigma(), 1.5, rtol=0.05)


def test_an_offset_foreground_does_not_inflate_the_estimate() -> None:
    # A sky darkening at dusk: the running background stays brighter than the frame,
    # and the foreground's mean drifts below zero (half a σ and more in simulated dusk).
    rng = np.random.default_rng(3)
    offset = np.array([[0.0, -0.6, -1.5, 0.8]], np.float32)
    noise = TileNoise((1, 4), window=30)
    for _ in range(30):
        frame = rng.normal(0, 1.2, (32, 128)).astype(np.float32)
        noise.update(frame + np.repeat(offset, 32, axis=1))
    np.testing.assert_allclose(noise.sigma(), 1.2, rtol=0.04)


def test_negative_side_sigma_inverts_the_gaussian_negative_half() -> None:
    from scipy.stats import norm

    mu = np.array([-3.0, -1.0, 0.0, 0.5, 2.0])
    sigma = np.array([1.0, 2.0, 1.5, 0.7, 1.0])
    t = mu / sigma
    share = norm.cdf(-t)
    mean_negative = sigma * (norm.pdf(t) - t * norm.cdf(-t))
    np.testing.assert_allclose(negative_side_sigma(mean_negative, share), sigma, rtol=1e-9)
    # μ = 0: the half-normal relation; no negative pixel: no estimate.
    np.testing.assert_allclose(
        negative_side_sigma(np.array([1.0]), np.array([0.5])), [2.5066], rtol=1e-4
    )
    assert negative_side_sigma(np.array([0.0]), np.array([0.0]))[0] == 0.0


def test_the_window_forgets_old_frames_exactly() -> None:
    rng = np.random.default_rng(2)
    noisy = [rng.normal(0, 3.0, (16, 16)).astype(np.float32) for _ in range(5)]
    calm = [rng.normal(0, 0.5, (16, 16)).astype(np.float32) for _ in range(4)]
    slid, fresh = TileNoise((1, 1), window=4), TileNoise((1, 1), window=4)
    for frame in [*noisy, *calm]:
        slid.update(frame)
    for frame in calm:
        fresh.update(frame)
    # Integer sums: a window that slid over other frames equals one started afresh.
    assert np.array_equal(slid.sigma(), fresh.sigma())


def test_before_any_frame_sigma_is_zero_and_grids_cover_the_image() -> None:
    assert np.all(TileNoise((3, 6), window=5).sigma() == 0)
    assert tile_grid((320, 640), 32) == (10, 20)
    assert tile_grid((10, 20), 32) == (1, 1)


def test_the_pixel_noise_floors_each_tile_and_is_rebuilt_only_after_an_update() -> None:
    noise = TileNoise((1, 2), window=4)
    left = np.zeros((4, 8), np.float32)
    left[:, :4] = np.tile([-2.0, 2.0], (4, 2))  # σ ≈ √(2π) on the left tile, 0 on the right
    noise.update(left)
    pixels = noise.pixel_noise((4, 8), floor=0.5, factor=2.5)
    sigma = pixels.sigma_at(np.arange(32)).reshape(4, 8)
    np.testing.assert_allclose(sigma[:, :4], noise.sigma()[0, 0])
    np.testing.assert_allclose(sigma[:, 4:], 0.5)
    np.testing.assert_array_equal(pixels.level, sigma * np.float32(2.5))
    before = pixels.level.copy()
    pixels.level[:] = -1.0  # not rebuilt until the noise changes: the same buffer comes back
    again = noise.pixel_noise((4, 8), floor=0.5, factor=2.5)
    assert np.shares_memory(again.level, pixels.level) and np.all(again.level == -1.0)
    noise.update(np.zeros((4, 8), np.float32))
    rebuilt = noise.pixel_noise((4, 8), floor=0.5, factor=2.5)
    np.testing.assert_allclose(rebuilt.sigma_at(np.array([0, 31])), [noise.sigma()[0, 0], 0.5])
    assert not np.array_equal(rebuilt.level, before)


@pytest.mark.parametrize("shape", [(30, 64), (31, 67), (960, 1920)])
def test_the_sigma_lookup_agrees_with_the_threshold_map(shape: tuple[int, int]) -> None:
    """Tiles that do not divide the image: each pixel's σ is the tile its map pixel took."""
    noise = TileNoise(tile_grid(shape, 32), window=2)
    rng = np.random.default_rng(0)
    noise.update((rng.normal(0, 1, shape) * rng.uniform(1, 3, shape[1])).astype(np.float32))
    pixels = noise.pixel_noise(shape, floor=0.0, factor=1.0)
    idx = np.arange(shape[0] * shape[1])
    np.testing.assert_array_equal(pixels.sigma_at(idx), pixels.level.ravel())
