"""The harder simulator (issue 7): the original scenarios unchanged bit for bit, and the new
knobs (dim/distant flashes, point-spread, streaks, colour, grain, bitrate, wind sway, sky
glints) doing what their truth columns say."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray
from pydantic import ValidationError

from pipeline.params import PatternParams
from pipeline.patterns import synchrony
from pipeline.simulate import SimulationConfig, ground_truth, load_truth, plan, simulate
from pipeline.simulation.config import SCENARIO_DEFAULTS, SCENARIOS, SPECIES_TIMINGS, FlashTiming
from pipeline.simulation.render import FIREFLY_RGB, LUMA, WHITE_FLASH_RGB, spot_sigma
from pipeline.simulation.tables import FlashTruth

REAL3D_CSV = Path(__file__).resolve().parents[3] / "shared/data/real-3d/xyzt_tent.csv"
ORIGINAL_COLUMNS = 16

#: SHA-256 of (a) every raw RGB frame of both cameras and (b) the truth files (the
#: original 16 flash columns + artifacts) of each original scenario at seed 1, 256 px,
#: 1 s, computed with the simulator BEFORE the issue-7 knobs existed (commit d359c9a).
#: Equal digests prove the defaults still render exactly the same recordings. Should a
#: numpy/scipy upgrade change them, re-check against d359c9a before updating them.
ORIGINAL_DIGESTS = {
    "clean": (
        "d1cffeec2e9a98ec67b55681844c2e74313e705e930f77bb690dc32500e8366e",
        "c32bb515c3778efe7b0a603b8361fbe8ab789b7294c5a4db2bad3a29122b40e7",
    ),
    "twilight": (
        "451403051d3577d2e2dc3b3f46b08a07bb0193c27200c9a278e483d3c8e24c81",
        "c32bb515c3778efe7b0a603b8361fbe8ab789b7294c5a4db2bad3a29122b40e7",
    ),
    "lights": (
        "ed52f23f3f47e9b1bd42a5736933f01adeb0bbe2f259480ff67ebbb3266e08fd",
        "774b6e745e2f507f67784f1adbf8c66898ba9f76cc86ed97ed979b4729ab5136",
    ),
    "headlights": (
        "e76a77402c759c1c9035d171158f41e419d647c560043ab257e6cc020191b234",
        "32006c8b8cca8b89476aabc648a844b581c3f0bf681fa0091c1d55f8e02f9258",
    ),
    "foliage": (
        "50f2b4e74a25516d4519e714807c31fcd3b740b883f20881b1f83961986e3fc4",
        "84ce795d9509e84d8a447422b03a39af47d568144ec3b5ac5fb0d6ce19b7fd36",
    ),
    "field": (
        "69b370a00a670d9ae09cd37715a4b4aae3b17563b9aa80c4e46e1695fbed9cce",
        "cd5cfb05afb967391962724e4344615c20ffd22896898310e63c52500b9fa98b",
    ),
    "real3d": (
        "b73923b738cdb04570a29b7cb11d562dfc0f9c4ecab68278701f8f29884c33fc",
        "12889c0bf3ec4b372cdc49978f125f467b3d03e33d9ea8ae1d925d904c4e5fc1",
    ),
}


@pytest.mark.parametrize("scenario", sorted(ORIGINAL_DIGESTS))
def test_original_scenarios_render_bit_identically(scenario: str, tmp_path: Path) -> None:
    fields: dict = {"scenario": scenario, "seed": 1, "width": 256, "seconds": 1.0}
    if scenario == "real3d":
        if not REAL3D_CSV.is_file():
            pytest.skip("needs ../shared/data/real-3d")
        fields["real3d_csv"] = REAL3D_CSV
    drawn = plan(SimulationConfig(**fields))
    frames = hashlib.sha256()
    for camera in (1, 2):
        renderer = drawn.renderer(camera)
        for k in range(drawn.config.n_frames):
            frames.update(renderer.render(k).tobytes())
    truth = drawn.truth()
    truth.flashes.to_csv(tmp_path / "f.csv")
    truth.artifacts.to_csv(tmp_path / "a.csv")
    lines = (tmp_path / "f.csv").read_text().splitlines()
    original = "\n".join(",".join(line.split(",")[:ORIGINAL_COLUMNS]) for line in lines) + "\n"
    files = hashlib.sha256(original.encode() + (tmp_path / "a.csv").read_bytes())
    assert (frames.hexdigest(), files.hexdigest()) == ORIGINAL_DIGESTS[scenario]


def test_hard_scenarios_are_documented_and_explicit_fields_win() -> None:
    for name in ("hard-clean", "hard-wind", "hard-all", "hard-swarm", "hard-species", "hard-noisy"):
        assert name in SCENARIOS and name in SCENARIO_DEFAULTS
    config = SimulationConfig(scenario="hard-clean")
    assert config.range_m == (2.0, 20.0) and config.motion_blur == 1.0
    assert config.bits_per_pixel == pytest.approx(0.16)
    mine = SimulationConfig(scenario="hard-clean", range_m=(2.0, 8.0), bits_per_pixel=None)
    assert mine.range_m == (2.0, 8.0) and mine.bits_per_pixel is None
    # A dumped configuration (truth.json) reloads to the same configuration.
    assert SimulationConfig.model_validate(config.model_dump(mode="json")) == config
    assert SimulationConfig().glints_per_branch == 0 and SimulationConfig().sway_px is None


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"flash_whiteness": (0.5, 1.5)}, "flash_whiteness"),
        ({"psf_sigma_px": (2.0, 1.0)}, "psf_sigma_px"),
        ({"intensity_range": (0.0, 1.0)}, "intensity_range"),
        ({"motion_blur": 1.5}, "motion_blur"),
        ({"swarms": 2, "range_m": (2.0, 8.0), "swarm_radius_m": 1.5}, "inside half the camera"),
    ],
)
def test_bad_hard_settings_are_rejected(settings: dict, message: str) -> None:
    with pytest.raises(ValidationError, match=message):
        SimulationConfig(**settings)


# -- truth columns -----------------------------------------------------------------------


def test_truth_columns_are_consistent() -> None:
    truth = ground_truth(SimulationConfig(scenario="hard-all", seed=3, seconds=10.0))
    f = truth.flashes
    for camera in (1, 2):
        position = f.position()
        if camera == 2:
            position = truth.pose.world_to_camera2(position, truth.separation_m)
        np.testing.assert_allclose(
            f.camera_column("range", camera), np.linalg.norm(position, axis=1)
        )
        amp, noise = f.camera_column("amp", camera), f.camera_column("noise", camera)
        np.testing.assert_allclose(f.camera_column("snr", camera), amp / noise)
        # Pixel integration and streaks only lower the drawn peak below the spot's peak.
        assert np.all(amp <= f.camera_column("peak", camera) + 1e-9)
        assert np.all(amp > 0.2 * f.camera_column("peak", camera))
        # Read 2, grain 3 and the dusk sky's shot noise.
        assert np.all(noise >= np.hypot(2.0, 3.0) - 1e-6) and np.all(noise < 8.0)
        psf = f.camera_column("psf", camera)
        assert psf.min() >= 0.6 and psf.max() <= 2.0
    assert f.whiteness.min() >= 0.0 and f.whiteness.max() <= 1.0 and np.ptp(f.whiteness) > 0.5


def test_original_scenarios_gain_truth_columns_with_their_old_meaning() -> None:
    truth = ground_truth(SimulationConfig(scenario="clean", seed=2, seconds=4.0))
    f = truth.flashes
    np.testing.assert_array_equal(f.psf1, spot_sigma(f.range1))
    assert np.all(f.streak_u1 == 0) and np.all(f.streak_v2 == 0) and np.all(f.whiteness == 0)
    np.testing.assert_allclose(f.noise1, f.noise1.mean(), rtol=0.05)  # dark sky: ~read noise
    assert np.all(f.noise1 > 1.5)
    assert np.all(f.snr1[f.visible1] > 20)  # the original fireflies are all bright


def test_truth_files_without_the_new_columns_still_load(tmp_path: Path) -> None:
    truth = ground_truth(SimulationConfig(seed=4, seconds=2.0))
    truth.save(tmp_path)
    path = tmp_path / "truth_flashes.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(",".join(x.split(",")[:ORIGINAL_COLUMNS]) for x in lines) + "\n")
    old = load_truth(tmp_path).flashes
    assert len(old) == len(truth.flashes)
    np.testing.assert_allclose(old.peak1, truth.flashes.peak1, atol=0.01)
    assert np.all(np.isnan(old.snr1)) and np.all(np.isnan(old.range2))
    # A row made from the original columns only (as older code does) fills them with NaN.
    row = FlashTruth(**{k: v[:1] for k, v in list(old.columns().items())[:ORIGINAL_COLUMNS]})
    assert np.isnan(row.amp1[0])
    path.write_text("\n".join(",".join(x.split(",")[:5]) for x in lines) + "\n")
    with pytest.raises(ValueError, match="header"):
        load_truth(tmp_path)


# -- what is drawn ------------------------------------------------------------------------


class Rise:
    """Raw RGB rise of frames over the same frames without fireflies (both renderers see
    the same frames in the same order, so their sensor noise is identical and cancels)."""

    def __init__(self, config: SimulationConfig, camera: int = 1) -> None:
        self.lit = plan(config).renderer(camera)
        self.dark = plan(config.model_copy(update={"n_fireflies": 0})).renderer(camera)

    def __call__(self, frame: int) -> NDArray[np.float64]:
        return self.lit.render(frame).astype(np.float64) - self.dark.render(frame)


def _isolated_rows(truth, frame: int, camera: int = 1, margin: float = 12.0) -> NDArray:
    f = truth.flashes
    k, u, v, visible = f.in_camera(camera)
    rows = np.flatnonzero(visible & (k == frame))
    keep = []
    for i in rows:
        du = (u[rows] - u[i] + truth.width / 2) % truth.width - truth.width / 2
        near = np.hypot(du, v[rows] - v[i]) < margin
        keep.append(near.sum() == 1 and 20 < v[i] < truth.height - 20)
    return rows[np.asarray(keep, dtype=bool)]


def _window(image: NDArray, u: float, v: float, half: int) -> NDArray:
    rows = np.clip(np.arange(round(v) - half, round(v) + half + 1), 0, image.shape[0] - 1)
    cols = np.mod(np.arange(round(u) - half, round(u) + half + 1), image.shape[1])
    return image[np.ix_(rows, cols)]


QUIET = {"noise_sigma": 0.0, "grain_sigma": 0.0, "seconds": 2.0, "seed": 5}


def test_drawn_peak_amplitude_and_colour_match_the_truth() -> None:
    """``amp`` is the largest luma rise of the flash's pixels; colour follows whiteness."""
    config = SimulationConfig(scenario="hard-clean", n_fireflies=40, **QUIET)
    truth = plan(config).truth()
    f = truth.flashes
    checked, ratios = 0, []
    rise_of = Rise(config)
    for frame in range(0, 60, 3):
        rise = rise_of(frame)
        for i in _isolated_rows(truth, frame):
            if not 15 < f.amp1[i] < 150:
                continue
            patch = _window(rise, f.u1[i], f.v1[i], 6)
            luma = patch @ LUMA
            assert luma.max() == pytest.approx(f.amp1[i], abs=1.0)
            peak = patch.reshape(-1, 3)[np.argmax(luma)]
            expected = (1 - f.whiteness[i]) * FIREFLY_RGB + f.whiteness[i] * WHITE_FLASH_RGB
            ratios.append((peak[2] / peak[1], expected[2] / expected[1], f.amp1[i]))
            checked += 1
    assert checked >= 10
    measured, expected, amp = np.array(ratios).T
    bright = amp > 60
    np.testing.assert_allclose(measured[bright], expected[bright], atol=0.08)
    assert np.ptp(expected) > 0.4  # yellow-green to nearly white


def test_motion_blur_streaks_flashes_along_their_motion() -> None:
    config = SimulationConfig(
        scenario="hard-clean",
        speed_mps=(4.0, 4.0),
        range_m=(2.0, 3.0),
        psf_sigma_px=(0.8, 0.8),
        n_fireflies=30,
        **QUIET,
    )
    truth = plan(config).truth()
    f = truth.flashes
    length = np.hypot(f.streak_u1, f.streak_v1)
    assert np.median(length[f.visible1]) > 1.5  # 4 m/s at 2-3 m: pixels at 640
    checked = 0
    rise_of = Rise(config)
    for frame in range(60):
        rise = rise_of(frame)
        for i in _isolated_rows(truth, frame, margin=20.0):
            if length[i] < 3.0 or f.amp1[i] < 10:
                continue
            luma = _window(rise, f.u1[i], f.v1[i], 8) @ LUMA
            weight = np.clip(luma, 0, None)
            dy, dx = np.mgrid[-8:9, -8:9] + np.array([round(f.v1[i]) - f.v1[i], 0])[:, None, None]
            dx = dx + round(f.u1[i]) - f.u1[i]
            direction = np.array([f.streak_u1[i], f.streak_v1[i]]) / length[i]
            along = dx * direction[0] + dy * direction[1]
            across = -dx * direction[1] + dy * direction[0]
            var_along = np.sum(weight * along**2) / weight.sum()
            var_across = np.sum(weight * across**2) / weight.sum()
            # A segment of length L adds L²/12 to the spread along it.
            assert var_along - var_across == pytest.approx(length[i] ** 2 / 12, rel=0.25)
            checked += 1
    assert checked >= 4


def test_grain_is_correlated_noise_of_the_stated_sigma() -> None:
    config = SimulationConfig(
        scenario="clean", n_fireflies=0, noise_sigma=1.0, grain_sigma=3.0, grain_px=1.2, seed=2
    )
    renderer = plan(config).renderer(1)
    a = renderer.render(0).astype(np.float64) @ LUMA
    b = renderer.render(1).astype(np.float64) @ LUMA
    ground = (a - b)[200:300] / np.sqrt(2)  # static dark ground: only noise changes
    expected = np.sqrt(1.0 + 3.0**2 + 0.04 * 5.5)  # read, grain, shot noise of ~5.5 luma
    assert ground.std() == pytest.approx(expected, rel=0.1)
    lag1 = np.mean(ground[:, 1:] * ground[:, :-1]) / ground.var()
    assert 0.6 < lag1 < 0.95  # GoPro night footage: ~0.86
    truth = ground_truth(config.model_copy(update={"n_fireflies": 10}))
    assert np.median(truth.flashes.noise1) == pytest.approx(expected, rel=0.1)


def test_bitrate_sets_the_file_size(tmp_path: Path) -> None:
    config = SimulationConfig(scenario="clean", seconds=3.0, bits_per_pixel=0.16, seed=1)
    recording = simulate(config, tmp_path)
    expected_bytes = 0.16 * 640 * 320 * 30 * 3.0 / 8
    for path in (*recording.cam1, *recording.cam2):
        assert path.stat().st_size == pytest.approx(expected_bytes, rel=0.35)


def test_wind_sways_branches_within_the_asked_amplitude_and_frequency() -> None:
    config = SimulationConfig(scenario="hard-wind", seed=2, seconds=10.0, n_fireflies=0)
    truth = ground_truth(config)
    art = truth.artifacts
    rows = (art.kind == "foliage") & (art.camera == 1)
    n_branches = 9
    u = art.u[rows].reshape(-1, n_branches)  # frame-major
    v = art.v[rows].reshape(-1, n_branches)
    stretch = 1.0 / np.sin(np.pi * v.mean(axis=0) / truth.height)
    du = (u - u.mean(axis=0) + truth.width / 2) % truth.width - truth.width / 2
    swing = np.hypot(du / stretch, v - v.mean(axis=0))
    amplitude = swing.max(axis=0)
    assert amplitude.min() > 0.8 and amplitude.max() < 6.6  # 1-6 px, seen from camera 1
    assert np.ptp(amplitude) > 1.5  # several amplitudes
    spectrum = np.abs(np.fft.rfft(du / stretch, axis=0))
    peak_hz = np.fft.rfftfreq(len(du), 1 / config.fps)[np.argmax(spectrum[1:], axis=0) + 1]
    assert peak_hz.min() >= 0.2 and peak_hz.max() <= 2.1


def test_sky_glints_blink_open_for_a_frame_or_two() -> None:
    config = SimulationConfig(scenario="hard-wind", seed=2, seconds=6.0, n_fireflies=0)
    truth = ground_truth(config)
    glints = truth.artifacts.select(
        (truth.artifacts.kind == "glint") & (truth.artifacts.camera == 1)
    )
    n_glints = 9 * config.glints_per_branch
    open_fraction = len(glints) / (n_glints * truth.n_frames1)
    assert 0.02 < open_fraction < 0.2
    foliage = plan(config).scene.foliage
    assert foliage is not None
    _, opening = foliage.glints(np.arange(truth.n_frames1))
    # Lengths of the runs of consecutive open frames, per glint.
    runs = np.concatenate(
        [np.diff(np.flatnonzero(np.diff(np.r_[0, col > 0, 0])))[::2] for col in opening.T]
    )
    assert np.median(runs) <= 3  # blinks, not steady lights
    # Rendered: holes in the dark canopy show bright sky spots that come and go.
    quiet = {"noise_sigma": 0.0, "grain_sigma": 0.0}
    without = plan(config.model_copy(update={"glints_per_branch": 0, **quiet})).renderer(1)
    with_glints = plan(config.model_copy(update=quiet)).renderer(1)
    peaks = []
    for frame in range(0, 60, 5):
        diff = (with_glints.render(frame).astype(float) - without.render(frame)) @ LUMA
        peaks.append(diff.max())
    assert max(peaks) > 40  # as bright as a flash
    assert min(peaks) >= 0.0


@pytest.mark.parametrize(("scenario", "synchronous"), [("hard-swarm", True), ("hard-clean", False)])
def test_swarm_fireflies_stay_in_their_clouds_and_flash_together(
    scenario: str, synchronous: bool
) -> None:
    config = SimulationConfig(scenario=scenario, seed=14)
    truth = ground_truth(config)
    f = truth.flashes
    recorded = f.frame1 >= 0  # flashes before camera 1 started are in the truth too
    found = synchrony(
        f.frame1[recorded], f.firefly_id[recorded], truth.n_frames1, config.fps, PatternParams()
    )
    assert found["synchronous"] is synchronous
    if not synchronous:
        return
    assert found["period_s"] == pytest.approx(np.mean(config.flash_period_s), abs=0.05)
    xyz = np.column_stack([f.x, f.y, f.z])
    for firefly in np.unique(f.firefly_id):
        extent = np.ptp(xyz[f.firefly_id == firefly], axis=0)
        assert np.all(extent <= 2 * config.swarm_radius_m + 1e-9)


@pytest.mark.parametrize("fps", [30.0, 60.0])
def test_species_keep_their_flash_pattern_in_seconds_at_any_frame_rate(fps: float) -> None:
    config = SimulationConfig(scenario="hard-species", seed=12, fps=fps)
    f = ground_truth(config).flashes
    flash, frames = np.unique(f.flash_id, return_counts=True)
    last = np.array([f.frame1[f.flash_id == i].max() for i in flash])
    whole = last < config.n_frames - 1  # a flash cut short by the end of the recording
    firefly = np.array([f.firefly_id[f.flash_id == i][0] for i in flash])
    medians = []
    for one in np.unique(firefly):
        seconds = frames[whole & (firefly == one)] / fps
        fits = [
            timing
            for timing in SPECIES_TIMINGS
            if np.all(seconds >= timing.flash_s[0] - 1 / fps)
            and np.all(seconds <= timing.flash_s[1] + 1 / fps)
        ]
        assert fits, f"firefly {one}: flashes of {seconds} s fit no pattern"
        medians.append(np.median(seconds) if len(seconds) else np.nan)
    # Quick pulses, brief flashes and long flashes on one night.
    bands = np.digitize(np.array(medians)[np.isfinite(medians)], [0.085, 0.22])
    assert set(bands) == {0, 1, 2}


def test_flash_timings_are_checked() -> None:
    with pytest.raises(ValidationError, match="overlap"):
        FlashTiming(flash_s=(0.2, 0.6), period_s=(0.5, 1.0), per_train=(2, 4), quiet_s=(1, 2))
    with pytest.raises(ValidationError, match="swarms"):
        SimulationConfig(scenario="hard-swarm", flash_timings=SPECIES_TIMINGS)
