"""Positions refined along the light curve (pipeline.refine)."""

from __future__ import annotations

import numpy as np

from pipeline.refine import refine_positions

WIDTH = 640


def _refine(frame, x, y, weight=None, chain=None, half_window=2):
    n = len(frame)
    weight = np.ones(n) if weight is None else np.asarray(weight, float)
    chain = np.zeros(n, np.intp) if chain is None else np.asarray(chain)
    return refine_positions(
        np.asarray(frame),
        np.asarray(x, float),
        np.asarray(y, float),
        weight,
        chain,
        WIDTH,
        half_window,
    )


def test_straight_motion_is_kept_exactly() -> None:
    frame = np.arange(10, 20)
    x, y = 100.0 + 0.7 * (frame - 10), 50.0 - 0.25 * (frame - 10)
    fx, fy = _refine(frame, x, y)
    np.testing.assert_allclose(fx, x, atol=1e-9)
    np.testing.assert_allclose(fy, y, atol=1e-9)


def test_noise_is_averaged_as_a_five_frame_fit_predicts() -> None:
    rng = np.random.default_rng(3)
    frame = np.tile(np.arange(12), 400)
    chain = np.repeat(np.arange(400), 12)
    x = 300.0 + 0.4 * frame + rng.normal(0, 0.3, frame.size)
    fx, _ = _refine(frame, x, np.full(frame.size, 80.0), chain=chain)
    inner = (frame >= 2) & (frame <= 9)  # full windows: the centre of 5 points, σ/√5
    ratio = np.std(fx[inner] - 300.0 - 0.4 * frame[inner]) / 0.3
    assert abs(ratio - 1 / np.sqrt(5)) < 0.03
    ends = (frame == 0) | (frame == 11)  # 3 points, extrapolated to an end: √(5/6) σ
    assert abs(np.std(fx[ends] - 300.0 - 0.4 * frame[ends]) / 0.3 - np.sqrt(5 / 6)) < 0.06


def test_the_fit_wraps_at_the_seam() -> None:
    frame = np.arange(6)
    true_x = np.mod(638.0 + 0.8 * frame, WIDTH)  # crosses u = 640 → 0
    noisy = np.mod(true_x + np.array([0.2, -0.2, 0.2, -0.2, 0.2, -0.2]), WIDTH)
    fx, _ = _refine(frame, noisy, np.full(6, 160.0))
    gap = np.mod(fx - true_x + WIDTH / 2, WIDTH) - WIDTH / 2
    assert np.all(np.abs(gap) < 0.2) and np.all((fx >= 0) & (fx < WIDTH))


def test_a_fit_near_the_zenith_stays_in_the_frame() -> None:
    frame = np.arange(4)
    y = np.array([0.05, 0.6, 1.8, 3.0])  # leaving the top row; the first fit lands at -0.06
    _, fy = _refine(frame, np.full(4, 50.0), y)
    assert fy[0] == 0.0 and np.all(np.diff(fy) > 0)
    _, fy = _refine(frame, np.full(4, 50.0), WIDTH / 2 - 1 - y)  # the nadir, mirrored
    assert fy[0] == WIDTH / 2 - 1


def test_weights_pull_a_faint_frame_onto_its_bright_neighbours() -> None:
    frame = np.arange(5)
    x = np.array([100.0, 101.0, 103.0, 103.0, 104.0])  # frame 2 is 1 px off the line
    weight = np.array([100.0, 100.0, 1.0, 100.0, 100.0])
    fx, _ = _refine(frame, x, np.zeros(5), weight=weight)
    assert abs(fx[2] - 102.0) < 0.05
    assert np.all(np.abs(fx[[0, 1, 3, 4]] - [100.0, 101.0, 103.0, 104.0]) < 0.05)


def test_short_or_ambiguous_chains_keep_their_measured_positions() -> None:
    # chain 0: two frames only; chain 1: two spots in frame 21; chain 2: alone.
    frame = np.array([0, 1, 20, 21, 21, 22, 23, 50])
    x = np.array([10.0, 11.3, 30.0, 31.2, 31.9, 32.1, 33.4, 70.0])
    chain = np.array([0, 0, 1, 1, 1, 1, 1, 2])
    fx, fy = _refine(frame, x, np.ones(8), chain=chain)
    np.testing.assert_array_equal(fx, x)
    np.testing.assert_array_equal(fy, np.ones(8))


def test_nothing_to_refine() -> None:
    fx, fy = _refine(np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
    assert fx.shape == fy.shape == (0,)
    x = np.array([1.0, 2.5, 2.9])
    fx, _ = _refine(np.arange(3), x, np.zeros(3), half_window=0)
    np.testing.assert_array_equal(fx, x)
