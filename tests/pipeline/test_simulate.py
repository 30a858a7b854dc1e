from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

import av
import numpy as np
import pytest
from numpy.typing import NDArray
from pydantic import ValidationError
from scipy import ndimage

from pipeline import simulate as simulate_module
from pipeline.geometry import angle_between, bearing_to_pixel, rotation_angle
from pipeline.simulate import (
    SimulatedRecording,
    SimulationConfig,
    ground_truth,
    load_truth,
    plan,
    simulate,
)
from pipeline.simulation.encode import ChapterWriter, chapter_sizes
from pipeline.simulation.render import FIREFLY_RGB, LUMA, add_spots

REAL3D_CSV = Path(__file__).resolve().parents[3] / "shared/data/real-3d/xyzt_tent.csv"
W, H = 640, 320


def decode_luma(paths: list[Path]) -> NDArray[np.uint8]:
    """Y planes of all frames of consecutive chapter files, shape (n, H, W)."""
    planes = []
    for path in paths:
        with av.open(str(path)) as container:
            planes += [frame.to_ndarray()[:H] for frame in container.decode(video=0)]
    return np.stack(planes)


def circular_du(a: NDArray, b: NDArray, width: int = W) -> NDArray:
    return (np.asarray(a) - b + width / 2) % width - width / 2


def window(image: NDArray, u: float, v: float, half: int) -> tuple[NDArray, NDArray, NDArray]:
    """Pixels around (u, v) with columns wrapped, and their row/column offsets."""
    r0, c0 = round(v), round(u)
    rows = np.clip(np.arange(r0 - half, r0 + half + 1), 0, image.shape[0] - 1)
    cols = np.mod(np.arange(c0 - half, c0 + half + 1), image.shape[1])
    offsets = np.arange(-half, half + 1)
    return image[np.ix_(rows, cols)].astype(np.float64), r0 + offsets, c0 + offsets


def centroid(signal: NDArray, u: float, v: float, half: int = 3) -> tuple[float, float]:
    """Intensity-weighted centroid (u, v) of the positive part of ``signal`` near (u, v)."""
    patch, rows, cols = window(signal, u, v, half)
    weight = np.clip(patch, 0, None)
    return float(weight.sum(axis=0) @ cols / weight.sum()), float(
        weight.sum(axis=1) @ rows / weight.sum()
    )


@pytest.fixture(scope="module")
def positive(tmp_path_factory: pytest.TempPathFactory) -> SimulatedRecording:
    config = SimulationConfig(seed=5, seconds=3.0, delay_frames=7, chapters=(2, 3))
    return simulate(config, tmp_path_factory.mktemp("positive"))


@pytest.fixture(scope="module")
def negative(tmp_path_factory: pytest.TempPathFactory) -> SimulatedRecording:
    config = SimulationConfig(seed=6, seconds=3.0, delay_frames=-11, codec="hevc")
    return simulate(config, tmp_path_factory.mktemp("negative"))


# -- ground truth ------------------------------------------------------------------------


def test_truth_projections_agree_with_geometry(positive: SimulatedRecording) -> None:
    truth = load_truth(positive.cam1[0].parent)
    f = truth.flashes
    assert len(f) > 20
    points = f.position()
    u1, v1 = bearing_to_pixel(points, truth.width)
    u2, v2 = bearing_to_pixel(truth.pose.world_to_camera2(points, truth.separation_m), truth.width)
    assert np.abs(circular_du(f.u1, u1)).max() < 1e-3
    assert np.abs(f.v1 - v1).max() < 1e-3
    assert np.abs(circular_du(f.u2, u2)).max() < 1e-3
    assert np.abs(f.v2 - v2).max() < 1e-3


def test_truth_files_round_trip(positive: SimulatedRecording) -> None:
    loaded = load_truth(positive.cam1[0].parent)
    truth = positive.truth
    assert (loaded.delay_frames, loaded.n_frames1, loaded.n_frames2) == (7, 90, 90)
    np.testing.assert_array_equal(loaded.pose.rotation, truth.pose.rotation)
    np.testing.assert_array_equal(loaded.pose.translation, truth.pose.translation)
    np.testing.assert_array_equal(loaded.flashes.flash_id, truth.flashes.flash_id)
    np.testing.assert_array_equal(loaded.flashes.visible2, truth.flashes.visible2)
    np.testing.assert_allclose(loaded.flashes.position(), truth.flashes.position(), atol=1e-6)
    assert loaded.extra["cam1"] == ["cam1_00.mp4", "cam1_01.mp4"]


@pytest.mark.parametrize("delay", [7, -11])
def test_frame2_is_frame1_plus_delay(delay: int) -> None:
    truth = ground_truth(SimulationConfig(seed=1, seconds=4.0, delay_frames=delay))
    f = truth.flashes
    np.testing.assert_array_equal(f.frame2 - f.frame1, delay)
    for camera, frame in ((1, f.frame1), (2, f.frame2)):
        visible = f.visible1 if camera == 1 else f.visible2
        # Without occlusion, visible means exactly "inside this camera's recording".
        np.testing.assert_array_equal(visible, (frame >= 0) & (frame < truth.n_frames1))
    # Each flash is listed in consecutive frames: one continuous emission of 3–6 frames.
    lengths = np.bincount(f.flash_id)
    assert lengths.min() >= 1 and lengths.max() <= 6
    assert np.median(lengths) >= 3


@pytest.mark.parametrize("name", ["positive", "negative"])
def test_same_flash_at_frame1_and_frame1_plus_delay(
    name: str, request: pytest.FixtureRequest
) -> None:
    recording: SimulatedRecording = request.getfixturevalue(name)
    truth = recording.truth
    luma1, luma2 = decode_luma(recording.cam1), decode_luma(recording.cam2)
    f = truth.flashes
    both = f.visible1 & f.visible2 & (f.peak1 > 70) & (f.peak2 > 70)
    checked = 0
    for flash in np.unique(f.flash_id[both])[:6]:
        rows = np.flatnonzero(f.flash_id == flash)
        if not (np.all(f.visible1[rows]) and np.all(f.visible2[rows])):
            continue
        seen1 = _lit_frames(luma1, f.u1[rows], f.v1[rows], f.frame1[rows])
        seen2 = _lit_frames(luma2, f.u2[rows], f.v2[rows], f.frame2[rows])
        assert seen1 == set(f.frame1[rows].tolist())
        assert seen2 == {k + truth.delay_frames for k in seen1}
        checked += 1
    assert checked >= 2


def _lit_frames(luma: NDArray, u: NDArray, v: NDArray, frames: NDArray) -> set[int]:
    """Frames within ±8 of a flash where the 3x3 neighbourhood of its truth position
    rises above 30 % of its largest rise over the per-pixel median."""
    lo, hi = max(int(frames.min()) - 8, 0), min(int(frames.max()) + 9, len(luma))
    background = np.median(luma, axis=0).astype(np.float64)
    rise = []
    for k in range(lo, hi):
        i = np.clip(np.searchsorted(frames, k), 0, len(frames) - 1)
        patch, _, _ = window(luma[k] - background, u[i], v[i], 1)
        rise.append(patch.max())
    rise_arr = np.array(rise)
    return {lo + int(i) for i in np.flatnonzero(rise_arr > 0.3 * rise_arr.max())}


# -- videos ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["positive", "negative"])
def test_decoded_size_count_and_chapters(name: str, request: pytest.FixtureRequest) -> None:
    recording: SimulatedRecording = request.getfixturevalue(name)
    config = SimulationConfig.model_validate(recording.truth.extra["config"])
    for camera, paths in ((1, recording.cam1), (2, recording.cam2)):
        assert [p.name for p in paths] == [f"cam{camera}_{i:02d}.mp4" for i in range(len(paths))]
        assert len(paths) == config.chapters[camera - 1]
        counts = []
        for path in paths:
            with av.open(str(path)) as container:
                stream = container.streams.video[0]
                assert stream.codec_context.name == config.codec
                assert (stream.width, stream.height) == (W, H)
                assert float(stream.average_rate) == pytest.approx(config.fps)
                frames = list(container.decode(video=0))
            assert all(f.width == W and f.height == H for f in frames)
            counts.append(len(frames))
        assert counts == chapter_sizes(config.n_frames, len(paths))
        assert sum(counts) == recording.truth.n_frames1 == config.n_frames


def test_flash_centroids_in_decoded_frames(positive: SimulatedRecording) -> None:
    truth = positive.truth
    luma = decode_luma(positive.cam1)
    background = np.median(luma, axis=0).astype(np.float64)
    f = truth.flashes
    candidates = np.flatnonzero(f.visible1 & (f.peak1 > 60) & (f.peak1 < 200))
    errors = []
    for i in candidates:
        same_frame = f.visible1 & (f.frame1 == f.frame1[i])
        others = np.hypot(circular_du(f.u1[same_frame], f.u1[i]), f.v1[same_frame] - f.v1[i])
        if np.sum(others < 10) > 1:
            continue  # another flash nearby would pull the centroid
        cu, cv = centroid(luma[f.frame1[i]] - background, f.u1[i], f.v1[i])
        errors.append(np.hypot(circular_du(cu, f.u1[i]), cv - f.v1[i]))
    assert len(errors) >= 20
    assert np.median(errors) < 0.15
    assert np.percentile(errors, 90) < 0.3


def test_spot_centroids_survive_encoding_including_seam(tmp_path: Path) -> None:
    u = np.array([0.3, W - 0.4, 100.25, 321.5, 450.8])
    v = np.array([150.6, 170.2, 160.0, 140.45, 181.9])
    sigma = np.array([1.0, 0.9, 1.2, 1.5, 0.6])
    background = np.full((H, W, 3), 12.5, dtype=np.float32)
    image = background.copy()
    add_spots(image, u, v, sigma, 150.0 * np.ones((5, 1)) * FIREFLY_RGB)
    path = tmp_path / "spots.mp4"
    with ChapterWriter([path], [2], "h264", 18, 30.0, W) as writer:
        writer.write(np.clip(background, 0, 255).astype(np.uint8))
        writer.write(np.clip(image, 0, 255).astype(np.uint8))
    empty, spots = decode_luma([path]).astype(np.float64)
    for ui, vi in zip(u, v, strict=True):
        cu, cv = centroid(spots - empty, ui, vi)
        assert abs(circular_du(cu, ui)) < 0.3 and abs(cv - vi) < 0.3, (ui, vi, cu, cv)
    # The spot at u = 0.3 really spans the seam: its left half lies in the last column.
    assert spots[151, W - 1] - empty[151, W - 1] > 20


# -- determinism, configuration ------------------------------------------------------------


def test_same_seed_same_truth_and_different_seed_differs() -> None:
    config = SimulationConfig(scenario="field", seed=3, seconds=4.0)
    a, b = ground_truth(config), ground_truth(config)
    c = ground_truth(config.model_copy(update={"seed": 4}))
    for name, column in a.flashes.columns().items():
        np.testing.assert_array_equal(column, getattr(b.flashes, name))
    for name, column in a.artifacts.columns().items():
        np.testing.assert_array_equal(column, getattr(b.artifacts, name))
    assert a.delay_frames == b.delay_frames
    np.testing.assert_array_equal(a.pose.rotation, b.pose.rotation)
    assert len(a.flashes) != len(c.flashes) or not np.allclose(a.flashes.x, c.flashes.x)
    assert rotation_angle(a.pose.rotation, c.pose.rotation) > 1e-6


def test_same_seed_same_pixels() -> None:
    config = SimulationConfig(scenario="headlights", seed=2, seconds=1.0)
    first = plan(config).renderer(2)
    second = plan(config).renderer(2)
    for frame in (0, 17):
        np.testing.assert_array_equal(first.render(frame), second.render(frame))


def test_cameras_rendered_at_once_give_the_same_files(tmp_path: Path) -> None:
    """Each camera in a process of its own (the default on several cores) writes the
    files of rendering them in turn, byte for byte, with progress for every frame."""
    config = SimulationConfig(scenario="hard-all", seed=4, seconds=1.0, chapters=(1, 2))
    digests = []
    for parallel in (False, True):
        frames: list[int] = []
        out = tmp_path / str(parallel)
        simulate(config, out, progress=frames.append, parallel=parallel)
        assert sum(frames) == 2 * config.n_frames
        digests.append({p.name: hashlib.sha256(p.read_bytes()).digest() for p in out.iterdir()})
    assert digests[0] == digests[1] and len(digests[0]) == 6  # 3 chapters + 3 truth files


def _fail_rendering(drawn: object, camera: int, out: Path, progress: object) -> None:
    if camera == 2:
        raise ValueError("camera 2 cannot be rendered")


def _die_rendering(drawn: object, camera: int, out: Path, progress: object) -> None:
    if camera == 2:
        os._exit(3)


@pytest.mark.parametrize(
    ("render", "error", "message"),
    [
        (_fail_rendering, ValueError, "camera 2 cannot be rendered"),
        (_die_rendering, RuntimeError, r"rendering camera 2 stopped \(exit code 3\)"),
    ],
)
def test_a_failing_render_process_fails_the_recording(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, render: object, error: type, message: str
) -> None:
    monkeypatch.setattr(simulate_module, "_render_camera", render)
    config = SimulationConfig(seed=1, seconds=0.5)
    with pytest.raises(error, match=message):
        simulate_module.render_in_processes(plan(config), tmp_path)


def _hang_rendering(drawn: object, camera: int, out: Path, progress: object) -> None:
    if camera == 2:
        time.sleep(600)


def test_a_hung_render_process_fails_the_recording(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(simulate_module, "_render_camera", _hang_rendering)
    monkeypatch.setattr(simulate_module, "RENDER_STALL_S", 2.0)
    config = SimulationConfig(seed=1, seconds=0.5)
    with pytest.raises(RuntimeError, match="rendering camera 2 made no progress for 2 s"):
        simulate_module.render_in_processes(plan(config), tmp_path)


def test_default_pose_is_side_by_side_and_roughly_parallel() -> None:
    for seed in range(20):
        truth = ground_truth(SimulationConfig(seed=seed, seconds=1.0, n_fireflies=0))
        axis = np.abs(truth.pose.translation)
        assert np.degrees(angle_between(axis, np.eye(3)[np.argmax(axis)])) < 12
        assert np.argmax(axis) in (0, 1)
        assert 0.9 < np.degrees(rotation_angle(truth.pose.rotation, np.eye(3))) < 6.1
        assert abs(truth.delay_frames) <= 30
    fixed = ground_truth(SimulationConfig(seconds=1.0, rotation_deg=4.0, delay_frames=-3))
    assert np.degrees(rotation_angle(fixed.pose.rotation, np.eye(3))) == pytest.approx(4.0)
    assert fixed.delay_frames == -3


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"scenario": "moonwalk"}, "unknown scenario 'moonwalk'"),
        ({"scenario": "real3d"}, "needs real3d_csv"),
        ({"scenario": "real3d", "real3d_csv": "/nonexistent.csv"}, "file not found"),
        ({"width": 642}, "multiple of 4"),
        ({"seconds": 2.0, "delay_frames": 40}, "delay_frames=40"),
        ({"flash_frames": (6, 3)}, "flash_frames"),
        ({"chapters": (0, 1)}, "at least one chapter"),
        ({"range_m": (0.5, 8.0)}, "range_m"),
        ({"occlusion": 1.5}, "occlusion"),
    ],
)
def test_bad_settings_are_rejected_with_a_clear_message(settings: dict, message: str) -> None:
    with pytest.raises(ValidationError, match=message):
        SimulationConfig(**settings)


# -- fireflies ---------------------------------------------------------------------------


def test_fireflies_fly_and_flash_like_fireflies() -> None:
    truth = ground_truth(SimulationConfig(seed=11))
    f = truth.flashes
    n = truth.n_frames1
    counts1 = np.bincount(f.frame1[f.visible1], minlength=n)[:n]
    counts2 = np.bincount(f.frame2[f.visible2], minlength=n + truth.delay_frames)
    k = np.arange(max(0, -truth.delay_frames), min(n, n - truth.delay_frames))
    single_pairs = np.sum((counts1[k] == 1) & (counts2[k + truth.delay_frames] == 1))
    assert single_pairs >= 150  # enough one-flash frames for spatial calibration
    assert np.mean(counts1 > 5) < 0.02
    distance = np.linalg.norm(f.position(), axis=1)
    assert distance.min() > 2.0 and distance.max() < 11.0
    assert np.mean(distance < 8.0) > 0.75
    altitude = f.z + truth.camera_height_m
    assert altitude.min() >= 0.2 - 1e-9 and altitude.max() <= 3.0 + 1e-9
    # Speed from consecutive frames of the same flash.
    same = (np.diff(f.flash_id) == 0) & (np.diff(f.frame1) == 1)
    speed = np.linalg.norm(np.diff(f.position(), axis=0)[same], axis=1) * truth.fps
    assert 0.2 < np.median(speed) < 1.0
    # Trains: a firefly's consecutive flashes are mostly 0.5–1 s apart, with long gaps.
    onsets = np.array([f.frame1[f.flash_id == i].min() for i in np.unique(f.flash_id)])
    owner = np.array([f.firefly_id[f.flash_id == i][0] for i in np.unique(f.flash_id)])
    order = np.lexsort((onsets, owner))
    gaps = np.diff(onsets[order])[np.diff(owner[order]) == 0] / truth.fps
    assert 0.45 < np.median(gaps) < 1.1
    assert np.max(gaps) > 3.0


def test_occlusion_hides_flashes_from_one_camera_only() -> None:
    truth = ground_truth(SimulationConfig(seed=2, occlusion=0.3))
    f = truth.flashes
    recorded1 = (f.frame1 >= 0) & (f.frame1 < truth.n_frames1)
    recorded2 = (f.frame2 >= 0) & (f.frame2 < truth.n_frames2)
    hidden1, hidden2 = recorded1 & ~f.visible1, recorded2 & ~f.visible2
    assert not np.any(hidden1 & hidden2)
    hidden_fraction = np.mean((hidden1 | hidden2)[recorded1 & recorded2])
    assert 0.2 < hidden_fraction < 0.4


def test_real3d_replays_the_real_swarm() -> None:
    truth = ground_truth(SimulationConfig(scenario="real3d", real3d_csv=REAL3D_CSV, seed=1))
    f = truth.flashes
    assert np.all(f.firefly_id == -1)
    assert len(np.unique(f.flash_id)) > 30
    real = np.loadtxt(REAL3D_CSV, delimiter=",")
    # A rigid placement: the replayed cloud has the real swarm's vertical extent.
    real_height = np.ptp(real[:, 2])
    assert np.ptp(f.z) <= real_height + 1e-6 and np.ptp(f.z) > 0.3 * real_height
    assert (f.z + truth.camera_height_m).min() == pytest.approx(0.3)
    distance = np.linalg.norm(f.position(), axis=1)
    assert distance.min() > 1.5 and distance.max() < 8.0
    # One flash moves little from frame to frame.
    same = np.diff(f.flash_id) == 0
    assert np.percentile(np.linalg.norm(np.diff(f.position(), axis=0)[same], axis=1), 95) < 0.2
    np.testing.assert_array_equal(f.frame2 - f.frame1, truth.delay_frames)
    # Three stretches of the data become three swarms around the rig, not one patch.
    azimuth = np.sort(np.degrees(np.arctan2(f.y, f.x)))
    assert np.max(np.diff(np.append(azimuth, azimuth[0] + 360))) < 170


# -- scenarios ---------------------------------------------------------------------------


def _luma_frames(scenario: str, frames: range, camera: int = 1) -> NDArray[np.float64]:
    renderer = plan(SimulationConfig(scenario=scenario, seed=4, seconds=2.0)).renderer(camera)
    return np.stack([renderer.render(k) @ LUMA for k in frames])


def _foreground_blobs(scenario: str) -> float:
    """Mean number of blobs per frame that a plain background subtraction (mean of the
    previous second) thresholded at 0.2 of full scale would report."""
    luma = _luma_frames(scenario, range(45))
    foreground = np.abs(luma[30:] - luma[:30].mean(axis=0)) > 51
    return float(np.mean([ndimage.label(mask)[1] for mask in foreground]))


def test_foliage_floods_background_subtraction_and_clean_does_not() -> None:
    assert _foreground_blobs("foliage") > 50
    assert _foreground_blobs("clean") < 5  # only the flashes themselves


def test_lamps_and_moon_are_static_saturated_blobs_seen_from_both_cameras() -> None:
    truth = ground_truth(SimulationConfig(scenario="lights", seed=4, seconds=2.0))
    art = truth.artifacts
    assert set(art.kind.tolist()) == {"lamp", "moon"}
    drawn = plan(SimulationConfig(scenario="lights", seed=4, seconds=2.0))
    for camera in (1, 2):
        rows = art.camera == camera
        assert np.all(np.bincount(art.frame[rows]) == 4)  # 3 lamps + moon in every frame
        image = drawn.renderer(camera).render(5) @ LUMA
        for i in np.flatnonzero(rows & (art.frame == 5)):
            patch, _, _ = window(image, art.u[i], art.v[i], 1)
            assert patch.max() > 250
        lamp = rows & (art.kind == "lamp")
        assert np.ptp(art.u[lamp & (art.frame == 0)] - art.u[lamp & (art.frame == 59)]) < 1e-9
    # A lamp's image position differs between cameras (parallax and rotation).
    first_lamp = (art.kind == "lamp") & (art.frame == 0)
    u1, u2 = art.u[first_lamp & (art.camera == 1)][0], art.u[first_lamp & (art.camera == 2)][0]
    assert abs(circular_du(u1, u2)) > 0.5


def test_headlights_move_and_flashlights_switch() -> None:
    truth = ground_truth(SimulationConfig(scenario="headlights", seed=4, seconds=20.0))
    art = truth.artifacts
    assert {"headlight", "taillight", "flashlight"} <= set(art.kind.tolist())
    head = (art.kind == "headlight") & (art.camera == 1)
    assert np.ptp(art.u[head]) > 20  # cars travel along the road
    torch = (art.kind == "flashlight") & (art.camera == 1)
    lit = np.zeros(truth.n_frames1, dtype=bool)
    lit[art.frame[torch]] = True
    assert np.sum(np.diff(lit.astype(int)) != 0) > 0  # switched on or off at least once


def test_twilight_sky_darkens() -> None:
    renderer = plan(SimulationConfig(scenario="twilight", seed=4, seconds=4.0)).renderer(1)
    sky_rows = slice(H // 2 - 60, H // 2 - 30)
    first = (renderer.render(0) @ LUMA)[sky_rows].mean()
    last = (renderer.render(119) @ LUMA)[sky_rows].mean()
    assert first > 3 * last
