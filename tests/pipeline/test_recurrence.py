"""The recurrence of a spot's brightness in the seconds before it (pipeline.recurrence)."""

from __future__ import annotations

import numpy as np

from pipeline.recurrence import MIN_SAMPLES, BrightHistory

SHAPE, FPS = (40, 80), 30.0
DARK, BRIGHT = 10, 120


def _history() -> BrightHistory:
    return BrightHistory(SHAPE, FPS, after_s=0.5, window_s=3.0, margin=3.0)


def _frame(*lit: tuple[int, int]) -> np.ndarray:
    image = np.full(SHAPE, DARK, np.uint8)
    for row, col in lit:
        image[row, col] = BRIGHT
    return image


def test_a_spot_lit_again_and_again_recurs_and_a_fresh_one_does_not() -> None:
    history = _history()
    for k in range(120):
        # A glint blinking with the sway (half of the time, one pixel to the side).
        history.add(k, _frame((10, 21)) if (k // 10) % 2 else _frame())
    now = _frame((10, 20), (30, 60))
    share = history.recurrence(120, now, np.array([10, 30]), np.array([20, 60]))
    assert 0.4 <= share[0] <= 0.6  # within the 3 × 3 neighbourhood, half the window
    assert share[1] == 0.0
    none = np.zeros(0, np.intp)
    assert history.recurrence(120, now, none, none).shape == (0,)  # a frame without candidates


def test_beside_a_static_light_only_a_flash_brighter_than_it_is_new() -> None:
    history = _history()
    lamp = _frame()
    lamp[10, 21] = 250  # a lit leaf, always there
    for k in range(120):
        history.add(k, lamp)
    now = lamp.copy()
    now[10, 20] = BRIGHT
    share = history.recurrence(120, now, np.array([10]), np.array([20]))
    assert share[0] == 1.0  # the neighbourhood is as bright as ever: it can't be told
    now[10, 20] = 255  # brighter than anything the spot showed before
    assert history.recurrence(120, now, np.array([10]), np.array([20]))[0] == 0.0


def test_a_flash_is_not_in_its_own_window() -> None:
    history = _history()
    for k in range(120):
        history.add(k, _frame((10, 20)) if k >= 110 else _frame())  # lit 10 frames, 0.33 s
    share = history.recurrence(120, _frame((10, 20)), np.array([10]), np.array([20]))
    assert share[0] == 0.0


def test_the_neighbourhood_wraps_at_the_seam() -> None:
    history = _history()
    for k in range(120):
        history.add(k, _frame((10, SHAPE[1] - 1)))
    share = history.recurrence(120, _frame((10, 0)), np.array([10]), np.array([0]))
    assert share[0] == 1.0


def test_a_dimmer_past_within_the_margin_counts_and_below_it_does_not() -> None:
    for past, expected in ((BRIGHT - 3, 1.0), (BRIGHT - 4, 0.0)):
        history = _history()
        for k in range(120):
            image = _frame()
            image[10, 20] = past
            history.add(k, image)
        share = history.recurrence(120, _frame((10, 20)), np.array([10]), np.array([20]))
        assert share[0] == expected


def test_too_short_a_past_is_not_measured() -> None:
    history = _history()
    first = round(0.5 * FPS)  # the most recent frames are not in the window
    k = first + 2 * (MIN_SAMPLES - 1) - 1  # every other frame is kept: MIN_SAMPLES - 1
    for j in range(k):
        history.add(j, _frame((10, 20)))
    spot = (np.array([10]), np.array([20]))
    assert np.isnan(history.recurrence(k, _frame((10, 20)), *spot)[0])
    history.add(k, _frame((10, 20)))
    assert history.recurrence(k + 1, _frame((10, 20)), *spot)[0] == 1.0
