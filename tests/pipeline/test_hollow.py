"""The dark hollow a light leaves where it was (pipeline.hollow)."""

from __future__ import annotations

import numpy as np

from pipeline.hollow import RECENT_S, hollow_depth
from pipeline.recurrence import BrightHistory

SHAPE, FPS, SIGMA = (40, 80), 30.0, 1.0
DARK, BRIGHT = 10, 110


def _frame(*lit: tuple[int, int]) -> np.ndarray:
    image = np.full(SHAPE, DARK, np.uint8)
    for row, col in lit:
        image[row, col] = BRIGHT
    return image


def _history(*lit: tuple[int, int], frames: int = 30) -> BrightHistory:
    history = BrightHistory(SHAPE, FPS, after_s=0.5, window_s=3.0, margin=3.0)
    for k in range(frames):
        history.add(k, _frame(*lit))
    return history


def _depth(history: BrightHistory, now: np.ndarray, *peaks: tuple[int, int], radius: int = 4):
    idx = np.array([r * SHAPE[1] + c for r, c in peaks], np.intp)
    # The candidates' response against a background without them: a lone pixel of
    # BRIGHT - DARK grey levels under a unit-sum Gaussian of σ = 1 (centre weight ~0.16).
    response = np.full(len(idx), 0.16 * (BRIGHT - DARK))
    return hollow_depth(now, 30, history, FPS, idx, response, radius, SIGMA)


def test_a_light_that_moved_leaves_a_hollow_and_a_flash_does_not() -> None:
    history = _history((10, 20))  # a lamp at (10, 20) until a moment ago
    now = _frame((10, 23), (30, 60))  # it moved 3 px; a flash lit up at (30, 60)
    moved, flash = _depth(history, now, (10, 23), (30, 60))
    assert moved < -0.9  # as deep as the light is bright
    assert flash == 0.0  # nothing changed around it but the flash itself
    # Searched over a square too small to reach where the lamp was, it has no hollow.
    assert _depth(history, now, (10, 23), radius=1)[0] > -0.05


def test_the_hollow_is_found_across_the_seam() -> None:
    history = _history((20, 78))
    now = _frame((20, 1))  # moved 3 px across the 360° seam
    assert _depth(history, now, (20, 1))[0] < -0.9


def test_only_the_frames_a_moment_before_count() -> None:
    # The lamp left (10, 20) a whole second ago: the recent frames no longer hold it.
    history = BrightHistory(SHAPE, FPS, after_s=0.5, window_s=3.0, margin=3.0)
    for k in range(30):
        history.add(k, _frame((10, 20)) if k < 30 - 1.5 * RECENT_S[1] * FPS else _frame())
    assert _depth(history, _frame((10, 23)), (10, 23))[0] == 0.0


def test_without_earlier_frames_nothing_is_measured() -> None:
    empty = BrightHistory(SHAPE, FPS, after_s=0.5, window_s=3.0, margin=3.0)
    assert np.isnan(_depth(empty, _frame((10, 23)), (10, 23))).all()
    assert _depth(empty, _frame(), radius=4).shape == (0,)
