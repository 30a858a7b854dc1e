"""Light a shifted earlier frame explains (pipeline.motion)."""

from __future__ import annotations

import cv2
import numpy as np

from pipeline.motion import LAGS_S, shifted_match
from pipeline.recurrence import BrightHistory

SHAPE, FPS, SIGMA, NOW = (40, 80), 30.0, 1.0, 30
DARK, BRIGHT = 10, 110
# Leaves and the sky between them: a random field smooth over a few pixels, 20-90 grey.
_FIELD = cv2.GaussianBlur(np.random.default_rng(7).normal(size=SHAPE), (0, 0), 2.0)
LEAVES = np.interp(_FIELD, (_FIELD.min(), _FIELD.max()), (20, 90)).astype(np.uint8)


def _frame(*lit: tuple[int, int], background: np.ndarray | None = None) -> np.ndarray:
    image = np.full(SHAPE, DARK, np.uint8) if background is None else background.copy()
    for row, col in lit:
        image[row : row + 2, col : col + 2] = BRIGHT  # a spot of 2 x 2 pixels
    return image


def _history(frames: dict[int, np.ndarray] | None = None, default: np.ndarray | None = None):
    """Frames 0 .. NOW − 1: `frames` where given, else `default`."""
    history = BrightHistory(SHAPE, FPS, after_s=0.5, window_s=3.0, margin=3.0)
    for k in range(NOW):
        history.add(k, (frames or {}).get(k, default if default is not None else _frame()))
    return history


def _match(history: BrightHistory, now: np.ndarray, *peaks: tuple[int, int], shift: int = 6):
    idx = np.array([r * SHAPE[1] + c for r, c in peaks], np.intp)
    return shifted_match(now, NOW, history, FPS, idx, shift, SIGMA)


def test_a_moved_light_is_explained_and_a_new_one_is_not() -> None:
    history = _history(default=_frame((10, 18)))  # a lamp at (10, 18) until now
    now = _frame((10, 23), (30, 60))  # it moved 5 px; a flash lit up at (30, 60)
    unexplained, gain = _match(history, now, (10, 23), (30, 60))
    moved, flash = unexplained
    assert np.all(np.abs(moved) < 0.05)  # the lamp 3 px back explains all of it
    assert np.all(gain[0] < 0.01)  # and far better than no shift
    assert np.all(flash > 0.95)  # nothing earlier explains the flash
    assert np.all(gain[1] == 1.0)  # its surroundings are still: no shift is better
    # Searched over shifts too small to reach where the lamp was, it is not explained.
    assert np.all(_match(history, now, (10, 23), shift=1)[0] > 0.9)


def test_a_flash_before_swaying_leaves_stays_new() -> None:
    before = np.roll(LEAVES, -3, axis=1)  # the leaves were 3 px to the left
    history = _history(default=before)
    now = _frame((20, 40), background=LEAVES)
    unexplained, gain = _match(history, now, (20, 40))
    assert np.all(gain < 0.7)  # the shift explains the leaves ...
    assert np.all(unexplained > 0.8)  # ... but not the flash in front of them
    # The leaves' own brightest pixel: carried by the sway, explained.
    row, col = np.unravel_index(np.argmax(LEAVES[5:35, 10:70]), (30, 60))
    leaf, leaf_gain = _match(history, LEAVES, (row + 5, col + 10))
    assert np.all(np.abs(leaf) < 0.05) and np.all(leaf_gain < 0.01)


def test_a_flash_in_its_later_frames_is_explained_by_its_first() -> None:
    # Lit since 4 frames ago: the frame 2 before holds it, the frame 8 before does not.
    history = _history({k: _frame((15, 30)) for k in range(NOW - 4, NOW)})
    (unexplained,), (gain,) = _match(history, _frame((15, 30)), (15, 30))
    assert round(LAGS_S[0] * FPS) == 2 and round(LAGS_S[1] * FPS) == 8
    assert abs(unexplained[0]) < 0.05 and unexplained[1] > 0.95
    assert gain[0] == 1.0  # explained where it is


def test_the_match_wraps_at_the_seam() -> None:
    history = _history(default=_frame((20, 77)))
    now = _frame((20, 1))  # moved 4 px across the 360° seam
    unexplained, _ = _match(history, now, (20, 1))
    assert np.all(np.abs(unexplained) < 0.05)


def test_without_earlier_frames_nothing_is_measured() -> None:
    empty = BrightHistory(SHAPE, FPS, after_s=0.5, window_s=3.0, margin=3.0)
    unexplained, gain = _match(empty, _frame((10, 23)), (10, 23))
    assert unexplained.shape == gain.shape == (1, len(LAGS_S))
    assert np.isnan(unexplained).all() and np.isnan(gain).all()
    unexplained, gain = _match(empty, _frame())
    assert unexplained.shape == gain.shape == (0, len(LAGS_S))
