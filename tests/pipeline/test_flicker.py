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


def test_faint_neighbours_do_not_make_a_bright_flash_flicker() -> None:
    """Grain around a bright flash train counts only as peers of grain; a bright
    flickering source still flickers however faint the grain around it."""
    rng = np.random.default_rng(1)
    train = flash_train(100, 300.0, 100.0)
    lit = np.flatnonzero(rng.random(600) < 0.7)
    moon = np.column_stack([lit, np.full(lit.size, 500.0), np.full(lit.size, 120.0)])
    # Faint grain in every frame within 3 px of both: 0.6 candidates a frame each.
    grain = np.vstack(
        [
            np.column_stack([f, x0 + rng.uniform(-3, 3, f.size), y0 + rng.uniform(-3, 3, f.size)])
            for x0, y0 in ((304.0, 101.0), (500.0, 120.0))
            for f in [np.flatnonzero(rng.random(600) < 0.6)]
        ]
    )
    cand = np.vstack([train, moon, grain])
    snr = np.concatenate(
        [np.full(len(train), 40.0), np.full(len(moon), 30.0), rng.uniform(4, 6, len(grain))]
    )
    params = FlickerParams()
    frame, x, y = cand[:, 0], cand[:, 1], cand[:, 2]
    every = flicker_duty(frame, x, y, WIDTH, FPS, params.radius_deg, params.window_s)
    peers = flicker_duty(
        frame, x, y, WIDTH, FPS, params.radius_deg, params.window_s, snr, params.peer_octaves
    )
    is_train = np.arange(len(cand)) < len(train)
    is_moon = (np.arange(len(cand)) >= len(train)) & (np.arange(len(cand)) < len(train) + len(moon))
    assert flickering(every, params)[is_train].all()  # the grain made it flicker
    assert not flickering(peers, params)[is_train].any()
    assert flickering(peers, params)[is_moon].mean() > 0.95
    # Grain counts every candidate at least as bright as itself: the train and the moon.
    assert (peers[~is_train & ~is_moon] <= every[~is_train & ~is_moon]).all()


def test_peer_octaves_compares_snr_on_a_half_octave_grid() -> None:
    frames = np.arange(121)  # one window of 2 s at 60 fps, centred on frame 60
    x = np.full(121, 100.0)
    # Every frame lit at the same spot; frame 60 is 8 σ, the others 2.9 σ.
    snr = np.full(121, 2.9)
    snr[60] = 8.0
    duty = flicker_duty(frames, x, x, WIDTH, FPS, 1.5, 2.0, snr, 1.0)
    assert duty[60] == pytest.approx(1 / 121)  # 2.9 is more than an octave below 8
    snr[:60] = 4.0  # 4 is one octave below 8: counted
    duty = flicker_duty(frames, x, x, WIDTH, FPS, 1.5, 2.0, snr, 1.0)
    assert duty[60] == pytest.approx(61 / 121)
    snr[:60] = np.nan  # an unknown SNR counts for everyone, and counts everyone
    duty = flicker_duty(frames, x, x, WIDTH, FPS, 1.5, 2.0, snr, 1.0)
    assert duty[60] == pytest.approx(61 / 121) and duty[0] == pytest.approx(61 / 121)
    assert flicker_duty(frames, x, x, WIDTH, FPS, 1.5, 2.0, snr, None)[60] == pytest.approx(1.0)
