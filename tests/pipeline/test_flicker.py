import numpy as np
import pytest

from pipeline.flicker import flicker_duty, flickering
from pipeline.params import FlickerParams

WIDTH, FPS = 640, 60.0


def flash_train(start: int, x0: float, y0: float, n_flashes: int = 5) -> np.ndarray:
    """A firefly's train: 5-frame flashes every 0.5 s, drifting 2 px per flash."""
    rows = [
        (start + 30 * k + i, x0 + 2.0 * k, y0 + 0.5 * k) for k in range(n_flashes) for i in range(5)
    ]
    return np.array(rows, dtype=np.float64)


def test_flash_trains_are_kept_and_a_flickering_spot_is_not() -> None:
    rng = np.random.default_rng(0)
    trains = np.vstack([flash_train(40 * i, 50.0 + 90 * i, 100.0) for i in range(5)])
    # Moonlight through leaves: the same spot (±0.7 px) lit in 70% of 600 frames.
    lit = np.flatnonzero(rng.random(600) < 0.7)
    moon = np.column_stack(
        [lit, 430 + rng.uniform(-0.7, 0.7, lit.size), 110 + rng.uniform(-0.7, 0.7, lit.size)]
    )
    cand = np.vstack([trains, moon])
    duty = flicker_duty(cand[:, 0], cand[:, 1], cand[:, 2], WIDTH, FPS)
    flagged = flickering(duty, FlickerParams())
    assert not flagged[: len(trains)].any()
    assert flagged[len(trains) :].mean() > 0.95


def test_duty_counts_neighbours_in_the_window_across_the_seam() -> None:
    frames = np.arange(121)
    # A source lit in every frame, straddling the 360° seam (x = 639.6 and x = 0.4).
    x = np.where(frames % 2 == 0, 639.6, 0.4)
    duty = flicker_duty(frames, x, np.full(121, 50.0), WIDTH, FPS, radius_deg=1.5, window_s=2.0)
    assert duty[60] == pytest.approx(1.0)  # a full window around the middle frame
    assert duty[0] == pytest.approx(61 / 121)  # only the later half exists
    far = flicker_duty(frames, x + 100 * (frames % 2), np.full(121, 50.0), WIDTH, FPS)
    assert far[60] == pytest.approx(61 / 121)  # every other frame is 100 px away


def test_disabled_and_empty() -> None:
    frames, xy = np.arange(100), np.full(100, 10.0)
    duty = flicker_duty(frames, xy, xy, WIDTH, FPS)
    assert not flickering(duty, FlickerParams(enabled=False)).any()
    assert flickering(duty, FlickerParams()).all()
    assert flicker_duty(np.zeros(0, int), np.zeros(0), np.zeros(0), WIDTH, FPS).shape == (0,)
