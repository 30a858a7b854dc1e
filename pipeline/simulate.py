"""Synthetic stereo 360° recordings of fireflies with exact ground truth.

Two equirectangular cameras side by side (GoPro Max / Fusion style) film a night
scene: fireflies flying and flashing a few metres away plus, depending on the
scenario, dusk sky, lamps, the moon, car headlights, flashlights and wind-shaken
foliage. Everything follows the CONTRACT conventions of DESIGN.md and
`pipeline.geometry`: camera 1 is the world frame (``z`` up, ground at
``z = −camera_height_m``), camera 2 sits at ``T = s t̂`` rotated by ``R``, and camera-1
frame ``k`` shows the same instant as camera-2 frame ``k + delay_frames``.

Usage::

    config = SimulationConfig(scenario="field", seed=3)
    recording = simulate(config, "out/")   # recording.cam1 / .cam2: chapter files in order
    truth = load_truth("out/")             # the same GroundTruth, read from its files
    truth = ground_truth(config)           # the truth alone, no video (fast)
    frame = plan(config).renderer(1).render(0)   # one raw RGB frame, before encoding

Randomness comes from independent streams per purpose (`pipeline.simulation.rig.stream`),
so the same seed gives the same truth and the same pixels.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import pickle
import queue
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.simulation.config import SCENARIOS, SimulationConfig
from pipeline.simulation.encode import ChapterWriter, chapter_sizes
from pipeline.simulation.fireflies import Emissions, synthetic_emissions
from pipeline.simulation.real3d import real_emissions
from pipeline.simulation.render import peak_weight, spot_peak, spot_sigma
from pipeline.simulation.rig import Rig, draw_rig, stream
from pipeline.simulation.scene import CameraRenderer, Scene, build_scene
from pipeline.simulation.snr import matched_filter_snr
from pipeline.simulation.tables import ArtifactTruth, FlashTruth
from pipeline.simulation.truth import GroundTruth

__all__ = [
    "SCENARIOS",
    "ArtifactTruth",
    "FlashTruth",
    "GroundTruth",
    "SimulatedRecording",
    "SimulationConfig",
    "SimulationPlan",
    "ground_truth",
    "load_truth",
    "plan",
    "simulate",
]


@dataclass(frozen=True)
class SimulatedRecording:
    """Output of `simulate`: chapter files of each camera, in order, and the truth."""

    cam1: list[Path]
    cam2: list[Path]
    truth: GroundTruth


@dataclass(frozen=True)
class SimulationPlan:
    """Everything drawn from a configuration before any pixel is rendered.

    Attributes
    ----------
    config : SimulationConfig
    rig : Rig
        Pose, delay, recording length, camera gains.
    scene : Scene
        Landscape, lights, foliage and sky level over time.
    flashes : FlashTruth
        The fireflies' flash-frames with their projections and visibility.
    """

    config: SimulationConfig
    rig: Rig
    scene: Scene
    flashes: FlashTruth

    def chapter_paths(self, out_dir: str | Path, camera: int) -> list[Path]:
        """``cam<camera>_00.mp4``, ``cam<camera>_01.mp4``, … in ``out_dir``."""
        count = self.config.chapters[camera - 1]
        return [Path(out_dir) / f"cam{camera}_{i:02d}.mp4" for i in range(count)]

    def truth(self) -> GroundTruth:
        """The ground truth (also what `simulate` writes next to the videos)."""
        rig, config = self.rig, self.config
        return GroundTruth(
            delay_frames=rig.delay_frames,
            pose=rig.pose,
            separation_m=rig.separation_m,
            camera_height_m=rig.camera_height_m,
            fps=config.fps,
            width=config.width,
            height=config.height,
            n_frames1=rig.n_frames,
            n_frames2=rig.n_frames,
            scenario=config.scenario,
            seed=config.seed,
            flashes=self.flashes,
            artifacts=self.scene.artifacts(),
            extra={
                "gains": list(rig.gains),
                "cam1": [p.name for p in self.chapter_paths(".", 1)],
                "cam2": [p.name for p in self.chapter_paths(".", 2)],
                "config": config.model_dump(mode="json"),
            },
        )

    def renderer(self, camera: int) -> CameraRenderer:
        """Renderer of ``camera``'s raw RGB frames (before encoding)."""
        return CameraRenderer(
            self.scene,
            camera,
            self.flashes,
            self.config.resolved_noise_sigma,
            stream(self.config.seed, f"noise{camera}"),
            grain_sigma=self.config.grain_sigma,
            grain_px=self.config.grain_px,
            grain_rng=stream(self.config.seed, f"grain{camera}"),
        )


def plan(config: SimulationConfig) -> SimulationPlan:
    """Draw the rig, the scene and the fireflies' flashes for ``config``."""
    rig = draw_rig(config)
    scene = build_scene(config, rig)
    flashes = flash_truth(emissions(config, rig), rig, config)
    return SimulationPlan(
        config=config, rig=rig, scene=scene, flashes=with_noise(flashes, scene, config)
    )


def ground_truth(config: SimulationConfig) -> GroundTruth:
    """The ground truth `simulate` would produce, without rendering any video (fast)."""
    return plan(config).truth()


def simulate(
    config: SimulationConfig,
    out_dir: str | Path,
    progress: Callable[[int], None] | None = None,
    parallel: bool | None = None,
) -> SimulatedRecording:
    """Render a stereo recording and write it with its ground truth.

    Parameters
    ----------
    config : SimulationConfig
    out_dir : str or Path
        Created if needed. Receives ``cam1_00.mp4``, ``cam1_01.mp4``, …,
        ``cam2_00.mp4``, …, ``truth.json``, ``truth_flashes.csv`` and
        ``truth_artifacts.csv``.
    progress : callable, optional
        Called with ``1`` after each frame is written (``2 * config.n_frames`` calls
        in all), e.g. ``tqdm.update``.
    parallel : bool, optional
        Render the two cameras at once, in a process each (`render_in_processes`); the
        files are the same byte for byte. None: when the machine has more than one core
        and the calling process may fork children.

    Returns
    -------
    SimulatedRecording
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    drawn = plan(config)
    if parallel is None:
        parallel = _worth_processes()
    if parallel:
        render_in_processes(drawn, out, progress)
    else:
        for camera in (1, 2):
            _render_camera(drawn, camera, out, progress)
    truth = drawn.truth()
    truth.save(out)
    return SimulatedRecording(
        cam1=drawn.chapter_paths(out, 1), cam2=drawn.chapter_paths(out, 2), truth=truth
    )


def load_truth(out_dir: str | Path) -> GroundTruth:
    """Ground truth written by `simulate` into ``out_dir``."""
    return GroundTruth.load(out_dir)


def emissions(config: SimulationConfig, rig: Rig) -> Emissions:
    """Flash-frames of the scenario's fireflies (synthetic or replayed real data)."""
    rng = stream(config.seed, "fireflies")
    if config.scenario == "real3d":
        assert config.real3d_csv is not None  # guaranteed by validation
        emitted = real_emissions(config.real3d_csv, config.fps, rig, rng, config.real3d_swarms)
    else:
        emitted = synthetic_emissions(config, rig, rng)
    lo, hi = config.intensity_range
    if lo == hi == 1.0:
        return emitted
    factor = _per_firefly(
        emitted,
        stream(config.seed, "brightness"),
        lambda r, n: np.exp(r.uniform(np.log(lo), np.log(hi), n)),
    )
    return dataclasses.replace(emitted, intensity=emitted.intensity * factor)


def _per_firefly(
    emitted: Emissions,
    rng: np.random.Generator,
    draw: Callable[[np.random.Generator, int], np.ndarray],
) -> np.ndarray:
    """A property drawn per firefly, per flash where the firefly is unknown (``-1``),
    broadcast to the emission rows."""
    per_firefly = draw(rng, int(emitted.firefly_id.max(initial=-1)) + 1)
    per_flash = draw(rng, int(emitted.flash_id.max(initial=-1)) + 1)
    known = emitted.firefly_id >= 0
    return np.where(
        known,
        per_firefly[np.where(known, emitted.firefly_id, 0)] if len(per_firefly) else 0.0,
        per_flash[emitted.flash_id] if len(per_flash) else 0.0,
    )


def velocities(flash_id: np.ndarray, frame: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Velocity (metres per frame, (n, 3)) of each flash-frame from the positions of the
    same flash in the neighbouring frames: central differences inside a flash,
    one-sided at its ends, zero for a flash seen in one frame only."""
    n = len(frame)
    order = np.lexsort((frame, flash_id))
    f, k, p = flash_id[order], frame[order], position[order]
    linked = (np.diff(f) == 0) & (np.diff(k) == 1)  # row i and i + 1 are consecutive frames
    step = np.diff(p, axis=0)
    forward = np.zeros((n, 3))
    backward = np.zeros((n, 3))
    has_next = np.zeros(n, dtype=bool)
    has_prev = np.zeros(n, dtype=bool)
    forward[:-1][linked], has_next[:-1] = step[linked], linked
    backward[1:][linked], has_prev[1:] = step[linked], linked
    count = has_next.astype(float) + has_prev
    velocity = np.zeros((n, 3))
    velocity[order] = (forward + backward) / np.maximum(count, 1.0)[:, None]
    return velocity


def flash_truth(emitted: Emissions, rig: Rig, config: SimulationConfig) -> FlashTruth:
    """Project emissions into both cameras and decide what each camera records.

    A flash-frame is visible in a camera when its frame lies in that camera's
    recording and the flash is not hidden by vegetation: a fraction
    ``config.resolved_occlusion`` of the flashes is hidden from one camera (drawn per
    flash: a firefly does not leave a leaf's shadow within a 0.1 s flash).
    """
    rng = stream(config.seed, "occlusion")
    n_flashes = int(emitted.flash_id.max(initial=-1)) + 1
    hidden = rng.random(n_flashes) < config.resolved_occlusion
    hidden_from = np.where(hidden, rng.integers(1, 3, n_flashes), 0)[emitted.flash_id]
    frame1 = emitted.frame1
    frame2 = rig.camera_frames(frame1, 2)
    n = len(frame1)
    whiteness = np.zeros(n)
    if config.flash_whiteness != (0.0, 0.0):
        lo, hi = config.flash_whiteness
        whiteness = _per_firefly(
            emitted, stream(config.seed, "colour"), lambda r, k: r.uniform(lo, hi, k)
        )
    psf_rng = stream(config.seed, "psf")
    half_exposure = (
        0.5 * config.motion_blur * velocities(emitted.flash_id, frame1, emitted.position)
    )
    columns = {}
    for camera, frame in ((1, frame1), (2, frame2)):
        u, v, distance = rig.project(emitted.position, camera)
        recorded = (frame >= 0) & (frame < rig.n_frames)
        columns[f"u{camera}"], columns[f"v{camera}"] = u, v
        columns[f"visible{camera}"] = recorded & (hidden_from != camera)
        gain = rig.gains[camera - 1]
        columns[f"peak{camera}"] = gain * spot_peak(
            emitted.intensity, distance, config.flash_brightness
        )
        columns[f"range{camera}"] = distance
        if config.psf_sigma_px is None:
            columns[f"psf{camera}"] = spot_sigma(distance)
        else:
            columns[f"psf{camera}"] = psf_rng.uniform(*config.psf_sigma_px, n_flashes)[
                emitted.flash_id
            ]
        du, dv = np.zeros(n), np.zeros(n)
        if config.motion_blur > 0:
            u0, v0, _ = rig.project(emitted.position - half_exposure, camera)
            u1, v1, _ = rig.project(emitted.position + half_exposure, camera)
            du = np.mod(u1 - u0 + rig.width / 2, rig.width) - rig.width / 2
            dv = v1 - v0
        columns[f"streak_u{camera}"], columns[f"streak_v{camera}"] = du, dv
        columns[f"amp{camera}"] = columns[f"peak{camera}"] * peak_weight(
            u, v, columns[f"psf{camera}"], du, dv
        )
    return FlashTruth(
        flash_id=emitted.flash_id,
        firefly_id=emitted.firefly_id,
        frame1=frame1,
        frame2=frame2,
        x=emitted.position[:, 0],
        y=emitted.position[:, 1],
        z=emitted.position[:, 2],
        intensity=emitted.intensity,
        whiteness=whiteness,
        **columns,
    )


def with_noise(flashes: FlashTruth, scene: Scene, config: SimulationConfig) -> FlashTruth:
    """``flashes`` with the noise σ at each flash's pixel (``noise1``, ``noise2``), the
    peak signal-to-noise ratios ``snr1 = amp1 / noise1``, ``snr2``, and the SNR at a
    matched filter's peak (``snr_mf1``, ``snr_mf2``: `matched_filter_snr`)."""
    columns = {}
    for camera in (1, 2):
        frame, u, v, _ = flashes.in_camera(camera)
        white = scene.noise_at(camera, frame, u, v, config.resolved_noise_sigma)  # read, shot
        noise = np.hypot(white, config.grain_sigma)  # the grain is independent of both
        columns[f"noise{camera}"] = noise
        amp = flashes.camera_column("amp", camera)
        columns[f"snr{camera}"] = amp / np.maximum(noise, 1e-9)
        streak = np.hypot(
            flashes.camera_column("streak_u", camera), flashes.camera_column("streak_v", camera)
        )
        columns[f"snr_mf{camera}"] = matched_filter_snr(
            amp,
            flashes.camera_column("psf", camera),
            streak,
            white,
            config.grain_sigma,
            config.grain_px,
        )
    return dataclasses.replace(flashes, **columns)


#: Seconds without a word from any render process after which they are stopped: a
#: frame takes well under a second even at 4K, so only a hung child stays this silent.
RENDER_STALL_S = 300.0


def _worth_processes() -> bool:
    return (
        (os.cpu_count() or 1) > 1
        and "fork" in multiprocessing.get_all_start_methods()
        and not multiprocessing.current_process().daemon  # a daemon may not have children
    )


def render_in_processes(
    drawn: SimulationPlan, out: Path, progress: Callable[[int], None] | None = None
) -> None:
    """Render and encode both cameras at once, one process each.

    Rendering is single-threaded numpy, so one camera leaves a core idle; each camera
    draws from random streams of its own, so the files are those of rendering the
    cameras in turn, byte for byte. The children are forked: a spawned one would import
    the caller's main module again (a script without a ``__main__`` guard would start
    over) and NumPy, SciPy and PyAV afresh; they only render with numpy and encode with
    encoders of their own. A child's exception is raised here; a child that dies without
    one raises RuntimeError.
    """
    context = multiprocessing.get_context("fork")
    messages: Any = context.Queue()
    workers = {
        camera: context.Process(
            target=_render_camera_process,
            args=(drawn, camera, out, messages),
            name=f"firefly3d-render-cam{camera}",
        )
        for camera in (1, 2)
    }
    for worker in workers.values():
        worker.start()
    try:
        running = set(workers)
        while running:
            kind, value = _next_message(messages, workers, running)
            if kind == "frames" and progress is not None:
                progress(value)
            elif kind == "done":
                running.discard(value)
            elif kind == "error":
                raise value
    finally:
        for worker in workers.values():
            if worker.is_alive():
                worker.terminate()
            worker.join()


def _next_message(
    messages: Any, workers: Mapping[int, BaseProcess], running: set[int]
) -> tuple[str, Any]:
    """The next message of the render processes; RuntimeError if one of those still
    running has stopped without a last word, or none has said anything for
    `RENDER_STALL_S`."""
    silent_s = 0.0
    while True:
        try:
            return messages.get(timeout=1.0)
        except queue.Empty:
            dead = [c for c in sorted(running) if workers[c].exitcode is not None]
            if not dead:
                silent_s += 1.0
                if silent_s >= RENDER_STALL_S:
                    cameras = " and ".join(str(c) for c in sorted(running))
                    raise RuntimeError(
                        f"rendering camera {cameras} made no progress for {silent_s:g} s"
                    ) from None
                continue
        try:  # its last message may have arrived just after the wait
            return messages.get(timeout=1.0)
        except queue.Empty:
            code = workers[dead[0]].exitcode
            raise RuntimeError(f"rendering camera {dead[0]} stopped (exit code {code})") from None


def _render_camera_process(drawn: SimulationPlan, camera: int, out: Path, messages: Any) -> None:
    """A child of `render_in_processes`: one camera, its progress and outcome as messages."""
    try:
        _render_camera(drawn, camera, out, lambda n: messages.put(("frames", n)))
    except Exception as exc:  # handed to the parent, which raises it
        try:
            pickle.dumps(exc)
        except Exception:  # some library errors do not pickle
            exc = RuntimeError(f"rendering camera {camera}: {exc!r}")
        messages.put(("error", exc))
    else:
        messages.put(("done", camera))


def _render_camera(
    drawn: SimulationPlan,
    camera: int,
    out: Path,
    progress: Callable[[int], None] | None,
) -> None:
    """Render and encode all frames of one camera into its chapter files."""
    config = drawn.config
    sizes = chapter_sizes(config.n_frames, config.chapters[camera - 1])
    renderer = drawn.renderer(camera)
    paths = drawn.chapter_paths(out, camera)
    bit_rate = None
    if config.bits_per_pixel is not None:
        bit_rate = round(config.bits_per_pixel * config.width * config.height * config.fps)
    with ChapterWriter(
        paths, sizes, config.codec, config.crf, config.fps, config.width, bit_rate=bit_rate
    ) as writer:
        for frame in range(config.n_frames):
            writer.write(renderer.render(frame))
            if progress is not None:
                progress(1)
