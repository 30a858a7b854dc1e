import numpy as np
import pytest
from pydantic import ValidationError

from pipeline.params import SyncParams
from pipeline.sync import SyncError, clean_counts, estimate_delay, window_votes

FPS = 30.0
MAX_LAG = round(SyncParams().max_delay_s * FPS)


def flash_counts(
    rng: np.random.Generator,
    delay: int,
    n1: int = 12_000,
    n2: int = 12_000,
    n_trains: int = 300,
    seen: float = 0.8,
    false_rate: float = 0.02,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame counts of two cameras watching the same Poisson bursts of flash trains.

    Camera-1 frame k is camera-2 frame k + delay. Each flash lasts 3 frames, each camera
    misses 20 % of them independently and adds its own false detections.
    """
    lo, hi = min(0, -delay) - 100, max(n1, n2 - delay) + 100
    onsets = rng.uniform(lo, hi, n_trains)
    n_flashes = rng.integers(3, 10, n_trains)
    period = rng.uniform(0.3, 0.8, n_trains) * FPS
    index = np.concatenate([np.arange(k) for k in n_flashes])
    start = np.floor(np.repeat(onsets, n_flashes) + index * np.repeat(period, n_flashes))
    frames = (start[:, None] + np.arange(3)).ravel().astype(np.int64)
    seen1 = frames[rng.random(len(frames)) < seen]
    seen2 = frames[rng.random(len(frames)) < seen] + delay
    counts1 = np.bincount(seen1[(seen1 >= 0) & (seen1 < n1)], minlength=n1)
    counts2 = np.bincount(seen2[(seen2 >= 0) & (seen2 < n2)], minlength=n2)
    return counts1 + rng.poisson(false_rate, n1), counts2 + rng.poisson(false_rate, n2)


@pytest.mark.parametrize("delay", [0, 1, 57, -57, -1234, 2500])
def test_recovers_delay_of_either_sign(delay: int) -> None:
    counts1, counts2 = flash_counts(np.random.default_rng(delay + 10_000), delay)
    est = estimate_delay(counts1, counts2, FPS)
    assert est.delay_frames == delay
    # Windows of camera 1 outside camera 2's recording (up to 21 %) cannot agree.
    assert est.confidence > 0.7
    assert est.warnings == ()
    assert est.n_windows == len(est.votes) == SyncParams().n_windows
    # The global curve peaks at the same delay.
    assert est.lags[np.argmax(est.correlation)] == delay


@pytest.mark.parametrize("delay", [MAX_LAG - 3, -(MAX_LAG - 3)])
def test_delay_near_the_search_bound(delay: int) -> None:
    counts1, counts2 = flash_counts(np.random.default_rng(7), delay)
    est = estimate_delay(counts1, counts2, FPS)
    assert est.delay_frames == delay
    assert est.lags.min() >= -MAX_LAG and est.lags.max() <= MAX_LAG


def test_delay_beyond_the_bound_is_not_found_and_warned() -> None:
    counts1, counts2 = flash_counts(np.random.default_rng(8), 900)
    est = estimate_delay(counts1, counts2, FPS, SyncParams(max_delay_s=10.0))
    assert abs(est.delay_frames) <= 300
    assert est.delay_frames != 900
    assert any("confidence" in w for w in est.warnings)


def test_light_pollution_bursts_are_suppressed() -> None:
    rng = np.random.default_rng(3)
    delay = -431
    counts1, counts2 = flash_counts(rng, delay)
    # Headlights: a few seconds in each camera, at unrelated times, with exploding counts.
    for counts in (counts1, counts2):
        for start in rng.integers(0, len(counts) - 200, 8):
            counts[start : start + 90] += rng.integers(40, 400, 90)
    est = estimate_delay(counts1, counts2, FPS)
    assert est.delay_frames == delay
    # Unsuppressed, the bursts drag confidence below 0.5 and the global peak elsewhere.
    assert est.confidence > 0.9
    assert est.lags[np.argmax(est.correlation)] == delay


def test_outlier_frames_are_neutral_and_empty_ends_trimmed() -> None:
    counts = np.zeros(100, dtype=np.int64)
    counts[20:80] = np.tile([0, 1, 2, 1], 15)
    counts[50] = 500
    clean = clean_counts(counts, outlier_mads=6.0)
    assert (clean.first, clean.last) == (21, 80)
    assert 50 not in clean.flash_frames
    assert clean.set_aside == 1
    centred = clean.centred()
    # The outlier frame holds the mean of the clean active frames: zero once centred.
    assert centred[50] == pytest.approx(0.0)
    assert np.all(centred[:21] == 0) and np.all(centred[80:] == 0)
    assert centred[21:80].sum() == pytest.approx(0.0, abs=1e-9)


def test_leading_and_trailing_empty_stretches() -> None:
    rng = np.random.default_rng(4)
    delay = 812
    counts1, counts2 = flash_counts(rng, delay)
    # Cameras started long before and stopped long after the fireflies.
    counts1 = np.concatenate([np.zeros(20_000, np.int64), counts1, np.zeros(15_000, np.int64)])
    counts2 = np.concatenate([np.zeros(20_000, np.int64), counts2, np.zeros(5_000, np.int64)])
    est = estimate_delay(counts1, counts2, FPS)
    assert est.delay_frames == delay
    assert est.confidence > 0.8


def test_independent_series_give_low_confidence_warning() -> None:
    rng = np.random.default_rng(5)
    counts1, _ = flash_counts(rng, 0)
    _, counts2 = flash_counts(rng, 0)
    est = estimate_delay(counts1, counts2, FPS)
    assert est.confidence < SyncParams().min_confidence
    assert any(w.startswith("low delay confidence") for w in est.warnings)


def test_agreement_tolerance_and_determinism() -> None:
    counts1, counts2 = flash_counts(np.random.default_rng(6), 100, seen=0.5, false_rate=0.2)
    exact = estimate_delay(counts1, counts2, FPS)
    again = estimate_delay(counts1, counts2, FPS)
    loose = estimate_delay(counts1, counts2, FPS, SyncParams(agree_frames=2))
    np.testing.assert_array_equal(exact.votes, again.votes)
    assert exact.delay_frames == loose.delay_frames == 100
    expected = np.mean(np.abs(exact.votes - 100) <= 2)
    assert loose.confidence == pytest.approx(expected)
    assert loose.confidence >= exact.confidence


def test_to_dict_is_json_ready() -> None:
    counts1, counts2 = flash_counts(np.random.default_rng(9), 5)
    est = estimate_delay(counts1, counts2, FPS)
    full, short = est.to_dict(), est.to_dict(include_curve=False)
    assert full["delay_frames"] == 5 and len(full["votes"]) == est.n_windows
    assert len(full["lags"]) == len(full["correlation"]) == 2 * MAX_LAG + 1
    assert "correlation" not in short


def test_camera_without_flashes_raises() -> None:
    counts1, _ = flash_counts(np.random.default_rng(1), 0)
    with pytest.raises(SyncError, match="camera 2 has no flashes"):
        estimate_delay(counts1, np.zeros(5000, np.int64), FPS)


def test_flashes_too_short_for_the_shortest_window_raise() -> None:
    # 4 s of flashes: a 3 s window (min_window_s) is more than two thirds of them.
    counts = np.ones(120, np.int64)
    with pytest.raises(SyncError, match="too short to estimate the delay"):
        estimate_delay(counts, counts, FPS)


@pytest.mark.parametrize("seed", range(8))
def test_flashes_shorter_than_a_window_shorten_it_with_a_warning(seed: int) -> None:
    # 9 s of a night at 30 fps, shorter than the 10 s window: 6 s windows.
    rng = np.random.default_rng(seed + 40)
    delay = int(rng.integers(-60, 60))
    counts1, counts2 = flash_counts(rng, delay, 270, 270, n_trains=10)
    est = estimate_delay(counts1, counts2, FPS)
    assert est.delay_frames == delay
    assert est.n_windows == SyncParams().n_windows
    assert any("windows shortened to" in w for w in est.warnings)
    assert est.confidence > SyncParams().min_confidence


def test_bad_input_raises_clear_errors() -> None:
    counts1, counts2 = flash_counts(np.random.default_rng(1), 0)
    with pytest.raises(ValueError, match="fps"):
        estimate_delay(counts1, counts2, 0.0)
    with pytest.raises(ValueError, match="counts2 must be a 1-D"):
        estimate_delay(counts1, counts2.reshape(2, -1), FPS)
    with pytest.raises(ValueError, match="non-negative"):
        estimate_delay(-counts1, counts2, FPS)
    with pytest.raises(ValidationError):
        SyncParams(n_windows=10)


def test_a_stretch_mostly_past_camera_2s_end_cannot_win() -> None:
    # Camera 1's window [0, 20) holds one flash, at frame 2. Camera 2 saw it at lag 10,
    # with a false neighbour; its lone flash at frame 73 is frame 2 at lag 71, where only
    # 7 of the window's 20 frames were recorded. A lone flash correlates perfectly with
    # any window, and lag 71 used to win.
    counts1, counts2 = np.zeros(80), np.zeros(80)
    counts1[[2, 30, 31, 50]] = 1
    counts2[[12, 13, 73]] = 1
    x1, x2 = counts1 - counts1.mean(), counts2 - counts2.mean()
    assert window_votes(x1, x2, np.array([0]), window=20, max_lag=75).tolist() == [10]


@pytest.mark.parametrize("seed", range(5))
def test_short_recordings_with_long_windows(seed: int) -> None:
    # 15 s at 60 fps: each 10 s window spans two thirds of the recording.
    counts1, counts2 = flash_counts(np.random.default_rng(seed), -40, 900, 900, n_trains=12)
    assert estimate_delay(counts1, counts2, 60.0).delay_frames == -40


def test_key_frame_bursts_in_step_do_not_pull_the_delay() -> None:
    # 12 s of a grainy night: both encoders code frames 0, 29, 58, ... whole and each
    # such frame bursts with confident speckle, in step in both cameras whatever the
    # delay. Read as flashes, the bursts vote for whole key intervals (0, ±29, ...):
    # a simulated 4K night (hard-noisy s12) was synchronised at -29 instead of -20.
    keys = np.arange(0, 360, 29)
    found, unaware = [], []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        counts1, counts2 = flash_counts(rng, -20, 360, 360, n_trains=16, false_rate=0.2)
        counts1[keys] += rng.poisson(3, len(keys))
        counts2[keys] += rng.poisson(3, len(keys))
        estimate = estimate_delay(counts1, counts2, FPS, key_frames=(keys, keys))
        assert estimate.set_aside == (len(keys), len(keys))
        found.append(estimate.delay_frames)
        unaware.append(estimate_delay(counts1, counts2, FPS).delay_frames)
    assert found == [-20] * 10
    assert sum(d != -20 for d in unaware) >= 6  # 8 of 10 when written


def test_an_intra_only_recording_keeps_every_frame() -> None:
    # Every frame a key frame (an all-intra mode): nothing bursts, nothing is neutralised.
    counts1, counts2 = flash_counts(np.random.default_rng(5), -20, 900, 900, n_trains=40)
    every = np.arange(900)
    plain = estimate_delay(counts1, counts2, FPS)
    intra = estimate_delay(counts1, counts2, FPS, key_frames=(every, every))
    assert intra.delay_frames == plain.delay_frames == -20
    assert np.array_equal(intra.votes, plain.votes)
    assert intra.set_aside == plain.set_aside == (0, 0)


def test_key_frames_are_neutral_like_outliers() -> None:
    counts = np.zeros(100, dtype=np.int64)
    counts[20:80] = np.tile([0, 1, 2, 1], 15)
    counts[[30, 60]] = 4
    clean = clean_counts(counts, outlier_mads=6.0, skip=np.array([-5, 30, 60, 20, 400]))
    assert not np.isin([20, 30, 60], clean.flash_frames).any()
    assert clean.set_aside == 3
    assert clean.first == 21
    assert clean.centred()[[30, 60]] == pytest.approx([0.0, 0.0])
