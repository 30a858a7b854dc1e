"""Flash-candidate tracking on synthetic videos with known spots (pipeline.tracking)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray
from pydantic import ValidationError

from pipeline.chunking import chunk_ranges, frames_read
from pipeline.detections import Detections
from pipeline.params import (
    BINNED_LIT_LEVEL,
    BINNED_SEED_LEVEL,
    LIT_LEVEL,
    SEED_LEVEL,
    TrackingParams,
)
from pipeline.probe import VideoInfo
from pipeline.tracking import (
    CLASSIFY_BATCH,
    PROGRESS_EVERY,
    track,
    track_with_stats,
)
from pipeline.video import iter_frames, probe_video
from tests.pipeline import video_factory as vf

H, W, FPS = 320, 640, 30.0
BACKGROUND = 20.0
# Short time constants so that 1–3 s videos exercise warm-up, blocks and absorption.
FAST = TrackingParams(tau_s=0.3, block_s=0.5, warmup_tau=1.0)


@dataclass
class CentreBrightness:
    """A real `PatchClassifier`: the brightest channel of the centre pixel, scaled to 0–1."""

    input_size: int = 9
    batch_sizes: list[int] = field(default_factory=list)

    def predict(self, patches: NDArray[np.uint8]) -> NDArray[np.float32]:
        self.batch_sizes.append(len(patches))
        centre = patches[:, self.input_size // 2, self.input_size // 2, :]
        return (centre.max(axis=-1) / 255.0).astype(np.float32)


@dataclass(frozen=True)
class Scene:
    info: VideoInfo
    truth: NDArray[np.float64]  # frame, u, v, amplitude


def _wrapped_distance(x: NDArray[np.float64], u: float) -> NDArray[np.float64]:
    return np.abs((x - u + W / 2) % W - W / 2)


@pytest.fixture(scope="module")
def spots(tmp_path_factory: pytest.TempPathFactory) -> Scene:
    """Every third frame shows six spots at random sub-pixel positions: one straddles
    the u = 0 seam, one touches the top pole and one the bottom pole."""
    rng = np.random.default_rng(7)
    pictures, truth = [], []
    for k in range(45):
        if k >= 6 and k % 3 == 0:
            u = rng.uniform(0, W, 6)
            v = rng.uniform(4, H - 4, 6)
            u[0] = rng.uniform(-0.5, 0.5) % W
            v[1] = rng.uniform(1.2, 2.0)
            v[2] = rng.uniform(H - 3.0, H - 2.2)
            amplitude = rng.uniform(120, 220, 6)
            truth += [(k, *row) for row in zip(u, v, amplitude, strict=True)]
        else:
            u = v = amplitude = np.zeros(0)
        pictures.append(vf.gaussian_spots(H, W, u, v, amplitude, 1.0, BACKGROUND))
    path = vf.write_video(tmp_path_factory.mktemp("spots") / "spots.mp4", pictures, crf=8)
    return Scene(probe_video([path]), np.array(truth))


def _match(detections: Detections, truth: NDArray[np.float64]) -> NDArray[np.intp]:
    """Row of the nearest detection in the same frame, for each true spot."""
    rows = []
    for k, u, v, _ in truth:
        in_frame = np.flatnonzero(detections.frame == k)
        distance = np.hypot(
            _wrapped_distance(detections.x[in_frame], u), detections.y[in_frame] - v
        )
        rows.append(in_frame[np.argmin(distance)])
    return np.array(rows)


def _centroid_errors(detections: Detections, truth: NDArray[np.float64]) -> NDArray[np.float64]:
    assert len(detections) == len(truth)  # nothing spurious, the seam spot not split
    rows = _match(detections, truth)
    assert len(set(rows.tolist())) == len(rows)
    assert np.all((detections.x >= 0) & (detections.x < W))
    dx = _wrapped_distance(detections.x[rows], truth[:, 1])
    return np.hypot(dx, detections.y[rows] - truth[:, 2])


@pytest.mark.parametrize("background", ["ewma", "box"])
def test_spots_are_found_once_with_subpixel_centroids(spots: Scene, background: str) -> None:
    params = FAST.model_copy(update={"background": background})
    error = _centroid_errors(track(spots.info, params=params), spots.truth)
    # Within 3 px of a pole the filter's replicated border row bends the spot.
    near_pole = np.minimum(spots.truth[:, 2], H - 1 - spots.truth[:, 2]) < 3
    assert error[~near_pole].max() < 0.1
    assert error[near_pole].max() < 0.3


def test_blurred_tracking_keeps_subpixel_centroids(spots: Scene) -> None:
    params = FAST.model_copy(update={"blur_px": 1.0})
    error = _centroid_errors(track(spots.info, params=params), spots.truth)
    # The blur widens spots to σ ≈ 1.4 px; near a pole their tail is cut by the frame edge.
    near_pole = np.minimum(spots.truth[:, 2], H - 1 - spots.truth[:, 2]) < 3
    assert error[~near_pole].max() < 0.1
    assert error[near_pole].max() < 0.75


def test_blob_measurements(spots: Scene) -> None:
    detections = track(spots.info, params=FAST)
    rows = _match(detections, spots.truth)
    u, v, amplitude = spots.truth[:, 1], spots.truth[:, 2], spots.truth[:, 3]
    # The brightest pixel is a pixel next to the true centre.
    peak_offset = np.hypot(
        _wrapped_distance(detections.peak_x[rows], u), detections.peak_y[rows] - v
    )
    assert peak_offset.max() <= math.sqrt(0.5) + 1e-9
    # Peak foreground: the spot's value at its nearest pixel, up to compression.
    expected_peak = amplitude * np.exp(-(peak_offset**2) / 2)
    assert np.abs(detections.peak[rows] - expected_peak).max() < 8
    # Filtered (σ = 1 px) a σ = 1 px spot is a σ = √2 px spot of peak A/2: above the
    # extent level ℓ within r² = 4 ln(A / 2ℓ), and ℓ >= extent_threshold × min_noise.
    level = FAST.extent_threshold * FAST.min_noise
    assert detections.area[rows].min() >= 9
    assert np.all(detections.area[rows] <= 4 * np.pi * np.log(amplitude / (2 * level)) + 6)
    assert np.all(np.isnan(detections.flash_probability))


def test_brightest_pixel_is_the_luminance_maximum_of_the_blob(spots: Scene) -> None:
    detections = track(spots.info, params=FAST)
    frames = {f.index: f.y.copy() for f in iter_frames(spots.info)}
    for k, px, py in zip(detections.frame, detections.peak_x, detections.peak_y, strict=True):
        luma = frames[int(k)]
        rows = np.clip(np.arange(py - 1, py + 2), 0, H - 1)
        window = luma[np.ix_(rows, np.arange(px - 1, px + 2) % W)]
        assert luma[py, px] == window.max()


@pytest.fixture(scope="module")
def lamps(tmp_path_factory: pytest.TempPathFactory) -> tuple[VideoInfo, dict[str, object]]:
    """Static lamps, a lamp switched on at frame 45, a slow ramp and a few flashes."""
    n = 90
    static = ([100.0, 400.0], [80.0, 250.0])
    switched = (300.0, 150.0)
    flashes = {20: (500.3, 60.6), 50: (200.7, 290.2), 75: (600.1, 30.4)}
    ramp_rows, ramp_cols = slice(200, 260), slice(60, 160)
    pictures = []
    for k in range(n):
        background = np.full((H, W), BACKGROUND)
        background[ramp_rows, ramp_cols] += 40.0 * k / n  # 13 grey levels per second
        u, v = list(static[0]), list(static[1])
        amplitude = [200.0, 200.0]
        if k >= 45:
            u.append(switched[0]), v.append(switched[1]), amplitude.append(200.0)
        if k in flashes:
            u.append(flashes[k][0]), v.append(flashes[k][1]), amplitude.append(180.0)
        pictures.append(vf.gaussian_spots(H, W, u, v, amplitude, 1.0, background))
    path = vf.write_video(tmp_path_factory.mktemp("lamps") / "lamps.mp4", pictures, crf=8)
    scene = {
        "static": static,
        "switched": switched,
        "flashes": flashes,
        "ramp": (ramp_rows, ramp_cols),
    }
    return probe_video([path]), scene


def _near(detections: Detections, u: float, v: float, radius: float = 3.0) -> NDArray[np.bool_]:
    return np.hypot(_wrapped_distance(detections.x, u), detections.y - v) < radius


@pytest.mark.parametrize("background", ["ewma", "box"])
def test_lamps_and_slow_ramps_are_absorbed(lamps: tuple[VideoInfo, dict], background: str) -> None:
    info, scene = lamps
    params = TrackingParams(tau_s=0.5, background=background)  # type: ignore[arg-type]
    detections = track(info, params=params)
    for u, v in zip(*scene["static"], strict=True):
        assert not np.any(_near(detections, u, v))
    rows, cols = scene["ramp"]
    in_ramp = (
        (detections.y >= rows.start - 2)
        & (detections.y < rows.stop + 2)
        & (detections.x >= cols.start - 2)
        & (detections.x < cols.stop + 2)
    )
    assert not np.any(in_ramp)
    for k, (u, v) in scene["flashes"].items():
        assert np.count_nonzero(_near(detections, u, v, 0.3) & (detections.frame == k)) == 1


def test_a_switched_on_lamp_fades_into_the_ewma_with_time_constant_tau(
    lamps: tuple[VideoInfo, dict],
) -> None:
    info, scene = lamps
    # A fixed noise level, so that the SNR is proportional to the foreground.
    params = TrackingParams(tau_s=0.5, min_noise=2.0, relative_noise=0.0, lit_update_rate=1.0)
    detections = track(info, params=params)
    seen = np.sort(detections.frame[_near(detections, *scene["switched"])])
    assert seen[0] == 45 and np.all(np.diff(seen) == 1)
    # Its foreground (and SNR S) decays as exp(-n / (τ fps)): seen while S > threshold.
    snr = detections.snr[_near(detections, *scene["switched"]) & (detections.frame == 45)]
    expected = math.floor(params.tau_s * FPS * math.log(snr[0] / params.seed_level(1))) + 1
    assert abs(len(seen) - expected) <= 2


def test_a_switched_on_lamp_still_fades_when_lit_pixels_are_slowed(
    lamps: tuple[VideoInfo, dict],
) -> None:
    info, scene = lamps
    params = TrackingParams(tau_s=0.2, min_noise=2.0, relative_noise=0.0, lit_update_rate=0.5)
    detections = track(info, params=params)
    seen = np.sort(detections.frame[_near(detections, *scene["switched"])])
    assert seen[0] == 45 and np.all(np.diff(seen) == 1)
    # Lit while it is seen, the lamp is folded in at half the rate: its foreground decays
    # as exp(-0.5 n / (τ fps)), twice as long as at full rate, and then it is gone.
    snr = detections.snr[_near(detections, *scene["switched"]) & (detections.frame == 45)]
    tau_frames = params.tau_s * FPS / params.lit_update_rate
    expected = math.floor(tau_frames * math.log(snr[0] / params.seed_level(1))) + 1
    assert abs(len(seen) - expected) <= 2
    assert seen[-1] < info.n_frames - 5
    for k, (u, v) in scene["flashes"].items():
        assert np.count_nonzero(_near(detections, u, v, 0.3) & (detections.frame == k)) == 1


def test_grain_is_learnt_alike_while_the_background_is_a_running_mean(tmp_path: Path) -> None:
    # The first frames' mean is grainy itself and lights pixels of the next frames; until
    # the model is an EWMA (τ · fps frames) they are learnt at the full rate.
    rng = np.random.default_rng(4)
    pictures = [np.clip(rng.normal(40.0, 4.0, (H, W)), 0, 255).astype(np.uint8) for _ in range(45)]
    info = probe_video([vf.write_video(tmp_path / "grain.mp4", pictures, crf=4)])
    params = TrackingParams(tau_s=0.5, block_s=10.0, lit_update_rate=1.0)
    full = track(info, params=params)
    slowed = track(info, params=params.model_copy(update={"lit_update_rate": 0.5}))
    running_mean = round(params.tau_s * FPS)
    _assert_same_rows(_in_range(slowed, 0, running_mean), _in_range(full, 0, running_mean))
    assert len(_in_range(full, 0, running_mean)) > 10
    assert len(slowed) != len(full)  # then the lit grain is learnt more slowly


@pytest.fixture(scope="module")
def flashing_in_place(tmp_path_factory: pytest.TempPathFactory) -> VideoInfo:
    """A spot lit 3 frames in every 10 at one place for 4 s (a swarm's firefly), after
    5 dark frames (the background starts as the first frame)."""
    dark = np.full((H, W), BACKGROUND, np.uint8)
    lit = vf.gaussian_spots(H, W, [320.4], [160.3], [80.0], 1.0, BACKGROUND)
    pictures = [lit if k >= 5 and (k - 5) % 10 < 3 else dark for k in range(125)]
    path = vf.write_video(tmp_path_factory.mktemp("in-place") / "in-place.mp4", pictures, crf=4)
    return probe_video([path])


def test_a_spot_flashing_in_place_lifts_a_slowed_background_less(
    flashing_in_place: VideoInfo,
) -> None:
    # A fixed noise level, so that the SNR is proportional to the foreground.
    params = TrackingParams(tau_s=1.0, min_noise=2.0, relative_noise=0.0)
    onsets = np.arange(5, 125, 10)
    snr = {}
    for rate in (1.0, 0.25):
        found = track(flashing_in_place, params=params.model_copy(update={"lit_update_rate": rate}))
        first = found.select(np.isin(found.frame, onsets) & _near(found, 320.4, 160.3))
        assert first.frame.tolist() == onsets.tolist()
        snr[rate] = first.snr
    # The first flash meets a dark background either way; then, over τ = 1 s, a 30 %
    # duty lifts the background to ~0.3 of the spot at full rate, to ~0.1 at a quarter.
    assert snr[0.25][0] == pytest.approx(snr[1.0][0])
    lifted = snr[1.0][-1] / snr[1.0][0]
    assert lifted < 0.8
    assert snr[0.25][-1] / snr[0.25][0] > lifted + 0.15


def test_a_switched_on_lamp_leaves_the_box_mean_after_a_fraction_of_tau(
    lamps: tuple[VideoInfo, dict],
) -> None:
    info, scene = lamps
    params = TrackingParams(tau_s=0.5, background="box", min_noise=2.0, relative_noise=0.0)
    detections = track(info, params=params)
    seen = np.sort(detections.frame[_near(detections, *scene["switched"])])
    assert seen[0] == 45 and np.all(np.diff(seen) == 1)
    # After m frames it fills m/L of the box: SNR S (1 − m/L) > threshold while
    # m < L (1 − threshold / S).
    box = round(params.tau_s * FPS)
    snr = detections.snr[_near(detections, *scene["switched"]) & (detections.frame == 45)]
    expected = math.ceil(box * (1 - params.seed_level(1) / snr[0]))
    assert abs(len(seen) - expected) <= 2


# -- exact chunking --------------------------------------------------------------------


@pytest.fixture(scope="module")
def flickering(tmp_path_factory: pytest.TempPathFactory) -> VideoInfo:
    """Three chapters (40, 35, 25 frames) of random spots over a flickering background."""
    rng = np.random.default_rng(11)
    pictures = []
    for k in range(100):
        m = int(rng.integers(0, 8))
        pictures.append(
            vf.gaussian_spots(
                H,
                W,
                rng.uniform(0, W, m),
                rng.uniform(0, H, m),
                rng.uniform(40, 220, m),
                rng.uniform(0.7, 1.5),
                BACKGROUND + 12 * math.sin(k / 6),
            )
        )
    directory = tmp_path_factory.mktemp("flicker")
    return probe_video(vf.write_chapters(directory, "cam1", pictures, [40, 35, 25], crf=20))


CUTS = [
    [0, 30, 60, 90, 100],  # on the EWMA block grid (15 frames)
    [0, 17, 41, 100],  # off the grid; [17, 41) spans the chapter boundary at 40
    [0, 40, 75, 100],  # exactly at the chapter boundaries
    [20, 70],  # not starting at 0, ending mid-chapter
    [33, 34, 35, 99],  # single frames
]


def _in_range(rows: Detections, start: int, stop: int) -> Detections:
    return rows.select((rows.frame >= start) & (rows.frame < stop))


def _assert_same_rows(actual: Detections, expected: Detections) -> None:
    for name, column in expected.columns().items():
        assert np.array_equal(getattr(actual, name), column, equal_nan=True), name


@pytest.mark.parametrize("background", ["ewma", "box"])
@pytest.mark.parametrize("cuts", CUTS, ids=lambda c: "-".join(map(str, c)))
def test_chunks_equal_the_unchunked_run_bit_for_bit(
    flickering: VideoInfo, background: str, cuts: list[int]
) -> None:
    params = FAST.model_copy(update={"background": background})
    whole = track_with_stats(flickering, params=params, classifier=CentreBrightness())
    assert len(whole.detections) > 150 and len(whole.faint_peaks) > 20
    parts = [
        track_with_stats(flickering, a, b, params, classifier=CentreBrightness())
        for a, b in itertools.pairwise(cuts)
    ]
    expected = _in_range(whole.detections, cuts[0], cuts[-1])
    assert np.isfinite(expected.recurrence).mean() > 0.5  # measured once the past fills
    _assert_same_rows(Detections.concat(p.detections for p in parts), expected)
    _assert_same_rows(
        Detections.concat(p.faint_peaks for p in parts),
        _in_range(whole.faint_peaks, cuts[0], cuts[-1]),
    )
    keys = whole.key_frames
    assert len(keys) > 0
    assert np.concatenate([p.key_frames for p in parts]).tolist() == [
        k for k in keys.tolist() if cuts[0] <= k < cuts[-1]
    ]


@pytest.mark.parametrize("background", ["ewma", "box"])
def test_planned_chunks_reassemble_the_whole_run(flickering: VideoInfo, background: str) -> None:
    params = FAST.model_copy(update={"background": background})
    ranges = chunk_ranges(flickering.n_frames, flickering.fps, params, chunk_s=1.0)
    assert ranges[0][0] == 0 and ranges[-1][1] == flickering.n_frames
    assert all(a[1] == b[0] for a, b in itertools.pairwise(ranges))
    whole = track(flickering, params=params)
    chunked = Detections.concat(track(flickering, a, b, params) for a, b in ranges)
    for name, column in whole.columns().items():
        assert np.array_equal(getattr(chunked, name), column, equal_nan=True), name


def test_chunk_ranges_follow_the_ewma_block_grid() -> None:
    params = TrackingParams()  # blocks of 30 s
    ranges = chunk_ranges(10_000, 29.97, params, chunk_s=100.0)
    block = round(30 * 29.97)
    assert all(start % block == 0 for start, _ in ranges)
    assert ranges[0][1] - ranges[0][0] == 3 * block  # 100 s rounds to 3 blocks
    assert ranges[-1][1] == 10_000
    short = chunk_ranges(10_000, 30.0, params, chunk_s=4.0)  # below half a block: as asked
    assert short[:2] == [(0, 120), (120, 240)] and short[-1] == (9960, 10_000)
    box = chunk_ranges(1000, 30.0, params.model_copy(update={"background": "box"}), 10.0)
    assert box[:2] == [(0, 300), (300, 600)] and box[-1] == (900, 1000)
    assert chunk_ranges(0, 30.0, params) == []
    with pytest.raises(ValueError, match="chunk_s must be positive"):
        chunk_ranges(100, 30.0, params, chunk_s=0)


def test_frames_read_covers_the_warm_up() -> None:
    short = FAST.model_copy(update={"recurrence_after_s": 0.1, "recurrence_window_s": 0.2})
    # EWMA: block 15 frames, warm-up 0.3 s = 9 frames before the block's start.
    assert frames_read(30, 60, FPS, short) == (21, 60)
    assert frames_read(37, 60, FPS, short) == (21, 60)
    assert frames_read(5, 10, FPS, short) == (0, 10)
    # Box: the 9 frames of the box before the start, and 9 + 2 more for its noise window.
    assert frames_read(37, 60, FPS, short.model_copy(update={"background": "box"})) == (17, 60)
    # The recurrence window (3 s = 90 frames) reaches further back than either.
    assert frames_read(200, 230, FPS, FAST) == (110, 230)
    assert frames_read(200, 230, FPS, FAST.model_copy(update={"background": "box"})) == (110, 230)


# -- classifier, progress, limits ------------------------------------------------------


def test_classifier_scores_the_patch_of_each_candidate(spots: Scene) -> None:
    classifier = CentreBrightness()
    detections = track(spots.info, params=FAST, classifier=classifier)
    # Patches were gathered across frames into one call (fewer than CLASSIFY_BATCH here).
    assert len(detections) < CLASSIFY_BATCH
    assert classifier.batch_sizes == [len(detections)]
    assert len(np.unique(detections.frame)) > 5
    # Row i got the score of its own patch: the grey centre pixel (BT.601 limited range).
    frames = {f.index: f.y.copy() for f in iter_frames(spots.info)}
    luma = np.array(
        [
            frames[int(k)][y, x]
            for k, x, y in zip(detections.frame, detections.peak_x, detections.peak_y, strict=True)
        ]
    )
    expected = np.clip(np.rint((luma - 16.0) * 255 / 219), 0, 255) / 255
    assert np.abs(detections.flash_probability - expected).max() <= 2 / 255


def test_progress_reports_every_frame_of_the_range_once(flickering: VideoInfo) -> None:
    calls: list[int] = []
    track(flickering, 25, 95, FAST, progress=calls.append)
    assert sum(calls) == 70
    assert len(calls) == math.ceil(70 / PROGRESS_EVERY)


def test_opencv_runs_on_one_thread_while_tracking_and_is_restored(
    flickering: VideoInfo,
) -> None:
    seen: list[int] = []
    cv2.setNumThreads(2)
    track(flickering, 25, 35, FAST, progress=lambda _: seen.append(cv2.getNumThreads()))
    assert seen and set(seen) == {1}
    assert cv2.getNumThreads() == 2


def test_spots_between_the_lit_and_seed_levels_are_faint_peaks(tmp_path: Path) -> None:
    # Clean video and a fixed noise σ of 2 grey levels: a σ = 1 px spot of amplitude A
    # peaks at A / 2 after the σ = 1 px matched filter, i.e. A / 4 σ.
    u, v, amplitude = [100.3, 300.6, 500.2], [80.4, 160.7, 240.1], [14.0, 40.0, 8.0]
    spot = vf.gaussian_spots(H, W, u, v, amplitude, 1.0, BACKGROUND)
    pictures = [np.full((H, W), BACKGROUND, np.uint8)] * 10 + [spot]
    info = probe_video([vf.write_video(tmp_path / "faint.mp4", pictures, crf=4)])
    fixed = FAST.model_copy(update={"min_noise": 2.0, "relative_noise": 0.0})
    result = track_with_stats(info, params=fixed)
    # Above the seed level (4 σ): a candidate; from 3 σ: a faint peak; below: nothing.
    assert len(result.detections) == 1 and abs(result.detections.x[0] - 300.6) < 0.2
    assert result.detections.snr[0] == pytest.approx(10.0, rel=0.1)
    faint = result.faint_peaks
    assert len(faint) == 1 and result.stats.faint_peaks == 1
    assert abs(faint.x[0] - 100.3) < 0.3 and abs(faint.y[0] - 80.4) < 0.3
    assert faint.frame[0] == 10 and 3.0 <= faint.snr[0] < 4.0
    assert np.isnan(faint.flash_probability[0])
    # Faint peaks are kept apart: without them the candidates are the same.
    off = track_with_stats(info, params=fixed.model_copy(update={"lit_threshold": 4.0}))
    assert len(off.faint_peaks) == 0
    _assert_same_rows(off.detections, result.detections)
    # A lower seed level makes the faint spot a candidate; its faint peak is gone.
    low = track_with_stats(info, params=fixed.model_copy(update={"threshold": 3.0}))
    assert len(low.detections) == 2 and len(low.faint_peaks) == 0
    capped = track_with_stats(
        info, params=fixed.model_copy(update={"max_faint_peaks_per_frame": 0})
    )
    assert len(capped.faint_peaks) == 0 and capped.stats.faint_over_cap == 1


def test_a_light_that_moved_leaves_a_dark_spot_and_a_flash_does_not(tmp_path: Path) -> None:
    # Frames 0-39: a lamp at u = 300; frame 40: it has jumped 3 px to the right, and a
    # flash lights up from nothing at u = 500. Both the running background and the frames
    # a moment before still hold the lamp where it was: beside its new position the frame
    # is darker than both (trough and hollow), beside the flash it is not.
    lamp = vf.gaussian_spots(H, W, [300.0], [160.0], [120.0], 1.0, BACKGROUND)
    moved = vf.gaussian_spots(H, W, [303.0, 500.0], [160.0] * 2, [120.0] * 2, 1.0, BACKGROUND)
    info = probe_video([vf.write_video(tmp_path / "moved.mp4", [lamp] * 40 + [moved], crf=4)])
    found = track_with_stats(info, params=FAST).detections
    last = found.select(found.frame == 40)
    at_lamp, at_flash = _near(last, 303.0, 160.0), _near(last, 500.0, 160.0)
    assert at_lamp.sum() == 1 and at_flash.sum() == 1
    assert last.trough[at_lamp][0] < -0.5 and last.hollow[at_lamp][0] < -0.5
    assert abs(last.trough[at_flash][0]) < 0.05 and abs(last.hollow[at_flash][0]) < 0.05
    # Searched over a square too small to reach where the lamp was, it has neither.
    near = track_with_stats(info, params=FAST.model_copy(update={"trough_radius_px": 1.0}))
    rows = near.detections.select(near.detections.frame == 40)
    assert rows.trough[_near(rows, 303.0, 160.0)][0] > -0.1
    assert rows.hollow[_near(rows, 303.0, 160.0)][0] > -0.1


def test_flooded_frame_is_capped_and_counted(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    pictures = [vf.gaussian_spots(H, W, [320.4], [160.6], [150.0], 1.0, BACKGROUND)] * 8
    flood = pictures[0].copy()
    flood[50:250, 100:500] = rng.choice([20, 255], (200, 400)).astype(np.uint8)
    pictures = [*pictures[:5], flood, *pictures[5:]]
    info = probe_video([vf.write_video(tmp_path / "flood.mp4", pictures, crf=8)])
    params = FAST.model_copy(update={"max_foreground_px": 2000, "max_candidates_per_frame": 20})
    result = track_with_stats(info, params=params)
    in_flood = result.detections.frame == 5
    assert np.count_nonzero(in_flood) == 20
    assert result.stats.flooded_frames == 1
    assert result.stats.dropped_over_cap > 0
    assert result.stats.frames == 9 and result.stats.candidates == len(result.detections)


@pytest.mark.parametrize(("rows", "flooded"), [(400, 1), (120, 0)])
def test_by_default_a_frame_floods_when_a_quarter_of_it_is_lit(
    tmp_path: Path, rows: int, flooded: int
) -> None:
    # A 1280 × 640 recording analysed in 2 × 2 bins (640 × 320 of them), half the
    # pixels of an 800-column band lit at random: 400 rows light most of 80,000 bins,
    # over a quarter of the frame; 120 rows light ~24,000 bins, which the fixed guard
    # this replaced (50,000 pixels of the recording, 12,500 bins) called flooded, as it
    # did every frame of a simulated grainy 4K night.
    height, width = 2 * H, 2 * W
    rng = np.random.default_rng(5)
    still = vf.gaussian_spots(height, width, [640.8], [321.2], [150.0], 2.0, BACKGROUND)
    lit = still.copy()
    lit[100 : 100 + rows, 200:1000] = rng.choice([20, 255], (rows, 800)).astype(np.uint8)
    info = probe_video([vf.write_video(tmp_path / "lit.mp4", [*[still] * 5, lit], crf=8)])
    params = FAST.model_copy(update={"bin_px": 2})
    assert track_with_stats(info, params=params).stats.flooded_frames == flooded


def test_binned_the_filter_stays_matched_to_spots_of_a_pixel(tmp_path: Path) -> None:
    # 4K spots are 1–2 px wide, so the filter stays matched in pixels of the recording
    # when the foreground is binned: spots of σ 0.7 px peaking at 7 σ of white sensor
    # noise reach the binned seed level (a filter of one bin, 2 px, found half of them).
    height, width, noise = 2 * H, 2 * W, 3.0
    rng = np.random.default_rng(11)
    u, v = np.meshgrid(np.arange(10) * 128.0 + 40.3, np.arange(6) * 80.0 + 120.6)
    frames = BACKGROUND + 10.0 + rng.normal(0.0, noise, (16, height, width))
    spots = vf.gaussian_spots(
        height, width, u.ravel(), v.ravel(), [7 * noise] * u.size, 0.7, frames[-1]
    )
    pictures = [*np.clip(np.rint(frames[:-1]), 0, 255).astype(np.uint8), spots]
    info = probe_video([vf.write_video(tmp_path / "small.mp4", pictures, crf=0)])
    found = track_with_stats(info, params=FAST.model_copy(update={"bin_px": 2})).detections
    lit = found.select(found.frame == 15)
    gap = np.hypot(u.reshape(-1, 1) - lit.x, v.reshape(-1, 1) - lit.y)
    assert np.count_nonzero(gap.min(axis=1) < 1.0) >= 0.95 * u.size
    # The seed level is raised with it: noise makes a few candidates a frame, not tens.
    noise_candidates = len(found) - np.count_nonzero(gap.min(axis=0) < 1.0)
    assert noise_candidates <= 10 * len(frames)


def test_blobs_outside_the_area_bounds_are_dropped(tmp_path: Path) -> None:
    big = np.full((H, W), BACKGROUND, np.uint8)
    big[100:110, 200:210] = 230  # 100 px: a lamp-sized blob
    small = vf.gaussian_spots(H, W, [500.2], [40.7], [200.0], 1.0, BACKGROUND)
    pictures = [np.full((H, W), BACKGROUND, np.uint8)] * 3 + [np.maximum(big, small)]
    info = probe_video([vf.write_video(tmp_path / "area.mp4", pictures, crf=8)])
    result = track_with_stats(info, params=FAST.model_copy(update={"max_area": 120}))
    assert len(result.detections) == 1
    assert abs(result.detections.x[0] - 500.2) < 0.2
    assert result.stats.dropped_by_area == 1


def test_a_flash_on_a_headlights_glow_is_found_and_the_glow_is_not(tmp_path: Path) -> None:
    # A glow of σ 6 px is one blob far over max_area; a flash 16 px from its centre
    # sits on its slope, a saturated square is a plateau with a rim.
    glow = (300.0, 160.0)
    flash = (316.3, 160.4)
    plateau = np.zeros((H, W))
    plateau[40:70, 500:540] = 230.0
    empty = np.full((H, W), BACKGROUND, np.uint8)
    lights = vf.gaussian_spots(H, W, [glow[0]], [glow[1]], [200.0], 6.0, BACKGROUND + plateau)
    lit = vf.gaussian_spots(H, W, [glow[0], flash[0]], [glow[1], flash[1]], [200.0, 80.0], 1.0)
    both = np.maximum(lights, lit)
    pictures = [empty] * 3 + [lights, empty, empty, both]
    info = probe_video([vf.write_video(tmp_path / "glow.mp4", pictures, crf=8)])
    found = track_with_stats(info, params=FAST).detections
    near_flash = _near(found, *flash, radius=1.0)
    assert np.count_nonzero(near_flash) == 1 and found.frame[near_flash][0] == 6
    # Nothing else but the glow's core: not its slope, the plateau or the plateau's rim.
    elsewhere = found.select(~near_flash)
    assert np.all(_near(elsewhere, *glow, radius=1.5))


def test_range_outside_the_video_is_refused(spots: Scene) -> None:
    with pytest.raises(ValueError, match=r"frame range \[40, 50\) is outside"):
        track(spots.info, 40, 50)


def test_parameters_are_validated() -> None:
    with pytest.raises(ValidationError, match="max_area"):
        TrackingParams(min_area=10, max_area=5)
    with pytest.raises(ValidationError, match="must not exceed block_s"):
        TrackingParams(tau_s=20.0, block_s=30.0)
    with pytest.raises(ValidationError, match="extent_threshold"):
        TrackingParams(threshold=3.0, extent_threshold=4.0)
    with pytest.raises(ValidationError, match="extent_threshold"):
        TrackingParams(extent_threshold=4.5)  # above the unbinned seed level
    with pytest.raises(ValidationError, match="tau"):
        TrackingParams(tau=2.0)  # type: ignore[call-arg]
    with pytest.raises(ValidationError, match="lit_update_rate"):
        TrackingParams(background="box", lit_update_rate=0.5)
    # The default rate is the EWMA's: a box mean asked for alone folds every frame in.
    assert TrackingParams().lit_update_rate == 0.5
    assert TrackingParams(background="box").lit_update_rate == 1.0


def test_the_default_levels_depend_on_the_binning_and_overrides_do_not() -> None:
    default = TrackingParams()
    assert (default.seed_level(1), default.lit_level(1)) == (SEED_LEVEL, LIT_LEVEL)
    assert (default.seed_level(2), default.lit_level(3)) == (BINNED_SEED_LEVEL, BINNED_LIT_LEVEL)
    chosen = TrackingParams(threshold=6.0, lit_threshold=3.5)
    assert (chosen.seed_level(2), chosen.lit_level(2)) == (6.0, 3.5)


@pytest.fixture(scope="module")
def pairs(tmp_path_factory: pytest.TempPathFactory) -> Scene:
    """Every third frame shows four pairs of spots 4 px apart, one five times fainter:
    a swarm's flashes side by side."""
    rng = np.random.default_rng(5)
    pictures, truth = [], []
    for k in range(45):
        u = v = amplitude = np.zeros(0)
        if k >= 6 and k % 3 == 0:
            u0, v0 = rng.uniform(20, W - 20, 4), rng.uniform(20, H - 20, 4)
            angle = rng.uniform(0, 2 * np.pi, 4)
            u = np.r_[u0, u0 + 4 * np.cos(angle)]
            v = np.r_[v0, v0 + 4 * np.sin(angle)]
            amplitude = np.r_[np.full(4, 150.0), np.full(4, 30.0)]
            truth += [(k, *row) for row in zip(u, v, amplitude, strict=True)]
        pictures.append(vf.gaussian_spots(H, W, u, v, amplitude, 1.4, BACKGROUND))
    path = vf.write_video(tmp_path_factory.mktemp("pairs") / "pairs.mp4", pictures, crf=8)
    return Scene(probe_video([path]), np.array(truth))


def test_deblending_finds_the_faint_flash_beside_a_bright_one(pairs: Scene) -> None:
    faint = pairs.truth[pairs.truth[:, 3] < 100]
    for deblend, expected in ((False, 0), (True, len(faint))):
        found = track(pairs.info, params=FAST.model_copy(update={"deblend": deblend}))
        rows = _match(found, faint)
        error = np.hypot(_wrapped_distance(found.x[rows], faint[:, 1]), found.y[rows] - faint[:, 2])
        assert np.count_nonzero(error < 1.0) == expected
    # Each pair is two candidates then, nothing more.
    assert len(found) == len(pairs.truth)


@pytest.mark.parametrize("cuts", CUTS[:2], ids=lambda c: "-".join(map(str, c)))
def test_chunks_equal_the_unchunked_run_with_lit_pixels_slowed(
    flickering: VideoInfo, cuts: list[int]
) -> None:
    params = FAST.model_copy(update={"lit_update_rate": 0.5})
    whole = track(flickering, params=params)
    full_rate = FAST.model_copy(update={"lit_update_rate": 1.0})
    assert not np.array_equal(whole.snr, track(flickering, params=full_rate).snr)
    parts = [track(flickering, a, b, params) for a, b in itertools.pairwise(cuts)]
    _assert_same_rows(Detections.concat(parts), _in_range(whole, cuts[0], cuts[-1]))


@pytest.mark.parametrize("cuts", CUTS[:2], ids=lambda c: "-".join(map(str, c)))
def test_chunks_equal_the_unchunked_run_with_deblending(
    flickering: VideoInfo, cuts: list[int]
) -> None:
    params = FAST.model_copy(update={"deblend": True})
    whole = track(flickering, params=params)
    parts = [track(flickering, a, b, params) for a, b in itertools.pairwise(cuts)]
    _assert_same_rows(Detections.concat(parts), _in_range(whole, cuts[0], cuts[-1]))
