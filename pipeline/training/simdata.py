"""Labelled patches from simulated recordings: the hard cases real data lacks.

For each (scenario, seed) the simulator renders a stereo recording; camera 1 is
tracked exactly as in production (`pipeline.tracking.track`, default parameters) with
a `PatchCollector` in the classifier's place, so the patches are the very ones the
classifier sees at run time. Each candidate is labelled against the ground truth:

- flash: within `pipeline.evaluate.DETECTION_TOLERANCE_PX` (equatorial pixels) of a
  visible true flash of the same frame,
- ambiguous (dropped): within `AMBIGUOUS_PX` but not that close (halo fragments,
  blobs merged with a lamp),
- background: everything else (lamps, headlights, flashlights, foliage edges, noise).

Only camera 1 is used: camera 2 films the same scene from 1–2 m away, so its patches
would be near-copies in the same group while adding half the rendering cost.
Backgrounds of a recording are subsampled (a static lamp gives near-identical patches
in every frame).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from pipeline.classify import FlashClassifier, center_crop_or_pad
from pipeline.detections import Detections
from pipeline.evaluate import DETECTION_TOLERANCE_PX
from pipeline.geometry import pixel_to_bearing
from pipeline.simulate import GroundTruth, SimulationConfig, simulate
from pipeline.tracking import PatchClassifier, track
from pipeline.training.dataset import PatchSet, save_patch_set
from pipeline.video import probe_video

AMBIGUOUS_PX = 5.0
#: Scenarios of the default data set: every kind of hard case the simulator has.
DEFAULT_SCENARIOS = ("clean", "twilight", "lights", "headlights", "foliage", "field")
#: Far from the small seeds tests and demos use, so no test recording is trained on.
DEFAULT_SEEDS = (101, 102, 103, 104)
MANIFEST = "simulated.json"


class PatchCollector:
    """A `pipeline.tracking.PatchClassifier` that keeps the patches it is shown.

    ``predict`` returns NaN probabilities; `patches` stacks what it received, in the
    order of the tracker's detection rows.
    """

    def __init__(self, input_size: int) -> None:
        self.input_size = input_size
        self._parts: list[NDArray[np.uint8]] = []

    def predict(self, patches: NDArray[np.uint8]) -> NDArray[np.float32]:
        """Store a copy of the patches; probability NaN."""
        self._parts.append(patches.copy())
        return np.full(len(patches), np.nan, dtype=np.float32)

    @property
    def patches(self) -> NDArray[np.uint8]:
        """(N, S, S, 3) uint8 RGB patches received so far."""
        if not self._parts:
            return np.zeros((0, self.input_size, self.input_size, 3), np.uint8)
        return np.concatenate(self._parts)


def label_candidates(detections: Detections, truth: GroundTruth, camera: int) -> NDArray[np.int8]:
    """1 flash, 0 background, -1 ambiguous, for each detection of ``camera``.

    Distances are chords between unit bearings scaled so that one equatorial pixel
    is 1 (the seam and the poles need no special case); a detection is compared
    with the visible true flashes of its own frame only.
    """
    frame, u, v, visible = truth.flashes.in_camera(camera)
    scale = truth.width / (2 * np.pi)
    true_pts = pixel_to_bearing(u[visible], v[visible], truth.width) * scale
    det_pts = pixel_to_bearing(detections.x, detections.y, truth.width) * scale
    labels = np.zeros(len(detections), dtype=np.int8)
    if len(true_pts) == 0 or len(det_pts) == 0:
        return labels
    # frames become a far-apart 4th coordinate: neighbours in other frames are never near
    spacing = 100.0 * scale
    tree = cKDTree(np.column_stack([true_pts, frame[visible] * spacing]))
    dist, _ = tree.query(np.column_stack([det_pts, detections.frame * spacing]))
    labels[dist < AMBIGUOUS_PX] = -1
    labels[dist <= DETECTION_TOLERANCE_PX] = 1
    return labels


@dataclass(frozen=True)
class SimulatedPatches:
    """Labelled patches of one simulated recording with their frame and centre pixel."""

    patches: PatchSet
    frames: NDArray[np.int64]
    centres: NDArray[np.int64]
    candidates: int
    ambiguous: int


def recording_patches(
    config: SimulationConfig,
    workdir: Path,
    size: int,
    max_flash: int,
    max_background: int,
    miner: PatchClassifier | None = None,
) -> SimulatedPatches:
    """Simulate ``config`` into ``workdir``, track camera 1 and label its candidates.

    At most ``max_flash`` flash and ``max_background`` background patches are kept
    (seeded random subsets: a flash lasts several nearly identical frames). With a
    ``miner`` (an existing classifier), half of the backgrounds are hard negatives:
    drawn with probability proportional to the miner's flash probability, so that
    rare structures it mistakes for flashes (the moon behind leaves, a sky gap in a
    tree) are well represented. The group of every patch is ``sim<scenario><seed>``.
    """
    recording = simulate(config, workdir)
    collector = PatchCollector(size)
    detections = track(probe_video(recording.cam1), classifier=collector)
    labels = label_candidates(detections, recording.truth, camera=1)
    rng = np.random.default_rng(config.seed)
    flashes = _at_most(np.flatnonzero(labels == 1), max_flash, rng)
    background = np.flatnonzero(labels == 0)
    if miner is not None and len(background) > max_background:
        hard = _hard_negatives(miner, collector.patches[background], max_background // 2, rng)
        rest = _at_most(np.delete(background, hard), max_background - len(hard), rng)
        background = np.concatenate([background[hard], rest])
    keep = np.sort(np.concatenate([flashes, _at_most(background, max_background, rng)]))
    group = f"sim{config.scenario}{config.seed}"
    patches = PatchSet(
        collector.patches[keep],
        labels[keep],
        np.full(len(keep), group),
        np.full(len(keep), ""),
        np.full(len(keep), "simulated"),
    )
    return SimulatedPatches(
        patches,
        detections.frame[keep],
        np.column_stack([detections.peak_x[keep], detections.peak_y[keep]]).astype(np.int64),
        candidates=len(detections),
        ambiguous=int((labels == -1).sum()),
    )


def _hard_negatives(
    miner: PatchClassifier, patches: NDArray[np.uint8], n: int, rng: np.random.Generator
) -> NDArray[np.intp]:
    """Indices of ``n`` patches drawn without replacement, weighted by flash probability."""
    weight = miner.predict(center_crop_or_pad(patches, miner.input_size)).astype(np.float64)
    weight += 1e-6  # every background stays possible
    return rng.choice(len(patches), n, replace=False, p=weight / weight.sum())


def _at_most(index: NDArray[np.intp], n: int, rng: np.random.Generator) -> NDArray[np.intp]:
    return rng.choice(index, n, replace=False) if len(index) > n else index


def build_simulated_dataset(
    out: str | Path,
    scenarios: Sequence[str] = DEFAULT_SCENARIOS,
    seeds: Sequence[int] = DEFAULT_SEEDS,
    seconds: float = 20.0,
    width: int = 640,
    size: int = 65,
    max_flash: int = 150,
    max_background: int = 300,
    miner: Path | None = None,
    progress: Callable[[int], None] | None = None,
) -> dict[str, object]:
    """Write a patch folder (``flash/``, ``background/``) from simulated recordings.

    Parameters
    ----------
    out : folder to create; also receives the manifest `MANIFEST` describing how the
        data was made (returned as well).
    scenarios, seeds : every scenario is simulated with every seed.
    seconds, width : length and equirectangular width (pixels) of each recording.
    size : patch side in pixels (65 lets the 65-pixel reference model be compared;
        smaller models centre-crop).
    max_flash, max_background : patches of each class kept per recording.
    miner : ONNX classifier whose likeliest false flashes make half of each
        recording's backgrounds (hard-negative mining, see `recording_patches`).
    progress : called with 1 after each recording.
    """
    out = Path(out)
    mining = FlashClassifier.load(miner) if miner is not None else None
    recordings = []
    with tempfile.TemporaryDirectory(prefix="firefly3d-sim-") as tmp:
        for scenario, seed in itertools.product(scenarios, seeds):
            config = SimulationConfig(scenario=scenario, seed=seed, seconds=seconds, width=width)
            workdir = Path(tmp) / f"{scenario}{seed}"
            sim = recording_patches(config, workdir, size, max_flash, max_background, mining)
            save_patch_set(sim.patches, out, sim.frames, sim.centres)
            recordings.append(
                {
                    "group": f"sim{scenario}{seed}",
                    "scenario": scenario,
                    "seed": seed,
                    "candidates": sim.candidates,
                    "flash_kept": int(sim.patches.labels.sum()),
                    "background_kept": int((sim.patches.labels == 0).sum()),
                    "ambiguous_dropped": sim.ambiguous,
                }
            )
            if progress:
                progress(1)
    manifest = {
        "made_by": "pipeline.training.simdata.build_simulated_dataset",
        "scenarios": list(scenarios),
        "seeds": list(seeds),
        "seconds": seconds,
        "width": width,
        "patch_size": size,
        "max_flash_per_recording": max_flash,
        "max_background_per_recording": max_background,
        "camera": 1,
        "hard_negative_miner": _describe(miner),
        "flash_radius_px": DETECTION_TOLERANCE_PX,
        "ambiguous_radius_px": AMBIGUOUS_PX,
        "recordings": recordings,
    }
    (out / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def _describe(model: Path | None) -> dict[str, str] | None:
    """Identity of a mining model: file, SHA-256 and its card's training command."""
    if model is None:
        return None
    card = FlashClassifier.load(model).card
    return {
        "file": str(model),
        "sha256": hashlib.sha256(model.read_bytes()).hexdigest(),
        "trained_by": str(card.training.get("command", "")),
    }


# --- Domain-randomised procedural patches --------------------------------------------
#
# Rendered directly as patches (no video, no tracker), so that tens of thousands cost
# seconds. Every nuisance that differs between cameras and nights is drawn at random:
# flash peak from the noise floor to saturation, point spread and motion streaks,
# colour from yellow-green to white, background from black sky to bright foliage, and
# per pseudo-recording the camera: white balance, gamma, grain and compression. The
# negatives are the things a tracker mistakes for flashes: foliage glints, lamps,
# headlights and the moon seen through leaves, plus wide out-of-focus blobs.

#: Kinds of procedural negatives (hard cases), drawn in equal shares.
NEGATIVE_KINDS = ("glints", "lamp", "headlights", "moon", "blob")
SYNTH_MANIFEST = "synthetic.json"
_MARGIN = 8  # canvas margin around the patch, so the brightest pixel can be re-centred


@dataclass(frozen=True)
class Camera:
    """Per-recording rendering of light into 8-bit RGB."""

    white_balance: NDArray[np.float64]  # (3,) channel gains
    gamma: float
    grain: float  # sensor noise σ, grey levels
    jpeg_quality: int  # 0: no compression
    chroma_blur: bool  # H.264-like 4:2:0 chroma
    saturation: float

    @classmethod
    def draw(cls, rng: np.random.Generator) -> Camera:
        """A random camera: a recording's colour, tone, noise and compression."""
        return cls(
            white_balance=np.exp(rng.normal(0.0, 0.12, 3)),
            gamma=float(rng.uniform(0.75, 1.3)),
            grain=float(rng.uniform(0.5, 6.0)),
            jpeg_quality=int(rng.choice([0, 40, 60, 75, 90])),
            chroma_blur=bool(rng.random() < 0.5),
            saturation=float(rng.uniform(0.5, 1.3)),
        )


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], sigma: float) -> np.ndarray:
    """Zero-mean unit-std spatially correlated noise."""
    import cv2

    field = cv2.GaussianBlur(rng.normal(0.0, 1.0, shape), (0, 0), sigma)
    return (field - field.mean()) / (field.std() + 1e-9)


def _background(rng: np.random.Generator, s: int) -> np.ndarray:
    """Linear-light background (s, s, 3), 0–255 scale: black sky to bright foliage."""
    kind = rng.choice(["black", "sky", "dim_foliage", "foliage"], p=[0.35, 0.2, 0.25, 0.2])
    if kind == "black":
        level, texture = rng.uniform(0, 12), rng.uniform(0, 2)
        tint = np.array([1.0, 1.0, rng.uniform(0.6, 1.4)])
    elif kind == "sky":
        level, texture = rng.uniform(5, 60), rng.uniform(0, 4)
        tint = np.array([rng.uniform(0.5, 1.0), rng.uniform(0.7, 1.0), rng.uniform(1.0, 1.8)])
    elif kind == "dim_foliage":
        level, texture = rng.uniform(5, 40), rng.uniform(3, 15)
        tint = np.array([rng.uniform(0.7, 1.1), rng.uniform(0.9, 1.3), rng.uniform(0.6, 1.1)])
    else:
        level, texture = rng.uniform(30, 140), rng.uniform(10, 45)
        tint = np.array([rng.uniform(0.7, 1.1), rng.uniform(0.9, 1.3), rng.uniform(0.6, 1.2)])
    yy, xx = np.mgrid[:s, :s] / s - 0.5
    gradient = 1.0 + rng.normal(0, 0.3) * yy + rng.normal(0, 0.3) * xx
    lum = level * gradient + texture * _smooth_noise(rng, (s, s), rng.uniform(1.0, 4.0))
    return np.clip(lum, 0, None)[..., None] * tint


def _psf(s: int, cy: float, cx: float, sigma: float, length: float, angle: float) -> np.ndarray:
    """Unit-peak Gaussian spot smeared along a line of ``length`` px (a motion streak)."""
    yy, xx = np.mgrid[:s, :s].astype(np.float64)
    steps = max(1, int(np.ceil(length)) + 1)
    offsets = np.linspace(-length / 2, length / 2, steps)
    out = np.zeros((s, s))
    for t in offsets:
        y, x = cy + t * np.sin(angle), cx + t * np.cos(angle)
        out += np.exp(-((yy - y) ** 2 + (xx - x) ** 2) / (2 * sigma**2))
    return out / out.max()


def _flash_rgb(rng: np.random.Generator) -> np.ndarray:
    """Unit-luma colour from yellow-green (0) to white (1)."""
    from pipeline.simulation.render import flash_colour

    return flash_colour(np.array([rng.uniform(0.0, 1.0) ** 0.7]))[0]


def _light_rgb(rng: np.random.Generator) -> np.ndarray:
    """Colour of artificial lights and reflections: sodium orange, warm or cold white,
    bluish LED; never the yellow-green of a firefly (green clearly above red), so that a
    large yellow-green blob, a firefly close to the lens, is not taught as a negative."""
    kind = rng.integers(4)
    if kind == 0:  # sodium / warm orange: red above green
        return np.array([1.0, rng.uniform(0.55, 0.8), rng.uniform(0.1, 0.4)])
    if kind == 1:  # warm white
        return np.array([1.0, rng.uniform(0.85, 0.95), rng.uniform(0.7, 0.9)])
    if kind == 2:  # cold white
        return np.array([rng.uniform(0.9, 1.0), 1.0, rng.uniform(1.0, 1.15)])
    return np.array([rng.uniform(0.6, 0.8), rng.uniform(0.8, 0.95), 1.0])  # bluish LED


def _add_flash(rng: np.random.Generator, canvas: np.ndarray, cy: float, cx: float) -> None:
    s = canvas.shape[0]
    sigma = rng.uniform(0.6, 2.0)
    length = rng.choice([0.0, rng.uniform(1.0, 12.0)], p=[0.6, 0.4])
    floor = float(canvas[..., 1].std()) + 3.0
    low = min(max(floor * 4, 25.0), 300.0)
    peak = float(np.exp(rng.uniform(np.log(low), np.log(600.0))))
    spot = _psf(s, cy, cx, sigma, length, rng.uniform(0, np.pi))
    canvas += spot[..., None] * peak * _flash_rgb(rng)


def _negative(rng: np.random.Generator, canvas: np.ndarray, kind: str) -> None:
    """Draw a hard negative centred on the canvas (in place)."""
    s = canvas.shape[0]
    c = s // 2
    yy, xx = np.mgrid[:s, :s].astype(np.float64)
    white = np.array([1.0, 1.0, 1.0])
    if kind == "glints":  # specular leaves: several irregular bright spots on foliage
        canvas += (rng.uniform(20, 90) * (1 + 0.3 * _smooth_noise(rng, (s, s), 3.0)))[..., None]
        near = [c + rng.uniform(-14, 14, 2) for _ in range(rng.integers(2, 8))]
        centres = [(c, c)] + [(y, x) for y, x in near]
        colour = np.array([rng.uniform(0.8, 1.0), 1.0, rng.uniform(0.8, 1.3)])
        for y, x in centres:
            sy, sx = rng.uniform(0.8, 3.5, 2)
            blob = np.exp(-((yy - y) ** 2 / (2 * sy**2) + (xx - x) ** 2 / (2 * sx**2)))
            canvas += blob[..., None] * rng.uniform(60, 400) * colour
    elif kind == "lamp":  # saturated core, wide halo, warm or cold white
        r = np.hypot(yy - c, xx - c)
        colour = _light_rgb(rng)
        core = rng.uniform(2.5, 7.0)
        halo = np.exp(-r / rng.uniform(4.0, 12.0)) * rng.uniform(60, 250)
        canvas += (np.clip(core + 0.5 - r, 0, 1) * 800 + halo)[..., None] * colour
    elif kind == "headlights":  # a pair of glaring lamps, or one with a beam
        sep = rng.uniform(6, 20)
        angle = rng.normal(0, 0.2)
        colour = np.array([rng.uniform(0.85, 1.0), rng.uniform(0.9, 1.0), rng.uniform(0.9, 1.3)])
        for side in (0.0, 1.0):
            y, x = c + side * sep * np.sin(angle), c + side * sep * np.cos(angle)
            r = np.hypot(yy - y, xx - x)
            glare = np.exp(-r / rng.uniform(2.0, 8.0)) * rng.uniform(100, 400)
            canvas += (np.clip(rng.uniform(1.0, 3.5) + 0.5 - r, 0, 1) * 700 + glare)[
                ..., None
            ] * colour
    elif kind == "moon":  # a bright disc broken up by dark leaves; centred on a gap
        offset = rng.uniform(-10, 10, 2)
        r = np.hypot(yy - c - offset[0], xx - c - offset[1])
        disc = np.clip(rng.uniform(8, 30) + 0.5 - r, 0, 1) * rng.uniform(150, 500)
        leaves = _smooth_noise(rng, (s, s), rng.uniform(1.5, 4.0)) > rng.uniform(-0.5, 0.8)
        leaves[c - 1 : c + 2, c - 1 : c + 2] = False
        glow = np.exp(-r / 15.0) * rng.uniform(10, 60)
        canvas *= np.where(leaves, 0.3, 1.0)[..., None]
        canvas += (np.where(leaves, 0.05, 1.0) * disc + glow)[..., None] * white
    else:  # wide out-of-focus blob (reflection, defocused lamp)
        sigma = rng.uniform(3.5, 8.0)
        blob = np.exp(-((yy - c) ** 2 + (xx - c) ** 2) / (2 * sigma**2))
        canvas += blob[..., None] * rng.uniform(40, 300) * _light_rgb(rng)


def _develop(rng: np.random.Generator, linear: np.ndarray, camera: Camera) -> np.ndarray:
    """Camera processing of linear light: white balance, grain, tone curve, saturation,
    clipping and compression -> uint8 RGB."""
    import cv2

    x = linear * camera.white_balance
    x = x + rng.normal(0.0, 1.0, x.shape) * (camera.grain + 0.05 * np.sqrt(np.maximum(x, 0)))
    x = 255.0 * (np.clip(x, 0, None) / 255.0) ** camera.gamma
    grey = x.mean(axis=2, keepdims=True)
    x = grey + camera.saturation * (x - grey)
    image = np.clip(np.rint(x), 0, 255).astype(np.uint8)
    if camera.chroma_blur:
        ycc = cv2.cvtColor(image, cv2.COLOR_RGB2YCrCb)
        h, w = ycc.shape[:2]
        for ch in (1, 2):
            small = cv2.resize(ycc[..., ch], (w // 2, h // 2), interpolation=cv2.INTER_AREA)
            ycc[..., ch] = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
        image = cv2.cvtColor(ycc, cv2.COLOR_YCrCb2RGB)
    if camera.jpeg_quality:
        _ok, data = cv2.imencode(
            ".jpg", image[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, camera.jpeg_quality]
        )
        decoded = cv2.imdecode(data, cv2.IMREAD_COLOR)
        assert decoded is not None  # OpenCV decodes what it just encoded
        image = decoded[..., ::-1]
    return np.ascontiguousarray(image)


def _recentre(image: np.ndarray, size: int) -> np.ndarray:
    """Crop ``size`` about the brightest pixel (channel sum) of the blob at the canvas
    centre, as the tracker centres its patches: climb to the maximum of the 9×9
    window until the centre is that maximum (at most ``_MARGIN`` px away)."""
    s = image.shape[0]
    lum = image.astype(np.int32).sum(axis=2)
    c = y = x = s // 2
    m = _MARGIN // 2
    for _ in range(8):
        window = lum[y - m : y + m + 1, x - m : x + m + 1]
        dy, dx = np.unravel_index(int(np.argmax(window)), window.shape)
        if window[dy, dx] == lum[y, x]:
            break
        y = int(np.clip(y - m + dy, c - _MARGIN, c + _MARGIN))
        x = int(np.clip(x - m + dx, c - _MARGIN, c + _MARGIN))
    h = size // 2
    return image[y - h : y - h + size, x - h : x - h + size]


def procedural_patches(
    n_recordings: int, per_recording: int, size: int = 65, seed: int = 0,
    flash_share: float = 0.5,
) -> PatchSet:  # fmt: skip
    """Domain-randomised labelled patches (module notes above), uint8 RGB.

    Each pseudo-recording (group ``synth<seed>r<k>``) has its own `Camera`; within it
    ``flash_share`` of the patches are flashes (on any background, sometimes with a
    second flash nearby), the rest negatives of `NEGATIVE_KINDS` in equal shares.
    Deterministic given ``seed``.
    """
    rng = np.random.default_rng(seed)
    s = size + 2 * _MARGIN
    c = s // 2
    images, labels, groups = [], [], []
    for k in range(n_recordings):
        camera = Camera.draw(rng)
        for i in range(per_recording):
            canvas = _background(rng, s)
            flash = rng.random() < flash_share
            if flash:
                _add_flash(rng, canvas, c + rng.uniform(-0.5, 0.5), c + rng.uniform(-0.5, 0.5))
            else:
                _negative(rng, canvas, NEGATIVE_KINDS[i % len(NEGATIVE_KINDS)])
            if rng.random() < 0.1:  # another firefly in view
                far = rng.uniform(8, size // 2, 2) * rng.choice([-1, 1], 2)
                _add_flash(rng, canvas, c + far[0], c + far[1])
            images.append(_recentre(_develop(rng, canvas, camera), size))
            labels.append(int(flash))
            groups.append(f"synth{seed}r{k}")
    n = len(labels)
    return PatchSet(
        np.stack(images),
        np.array(labels, dtype=np.int8),
        np.array(groups),
        np.full(n, ""),
        np.full(n, "procedural"),
    )


def build_procedural_dataset(
    out: str | Path, n_recordings: int = 12, per_recording: int = 600, size: int = 65,
    seed: int = 0,
) -> dict[str, object]:  # fmt: skip
    """Write `procedural_patches` as a patch folder plus its manifest `SYNTH_MANIFEST`."""
    out = Path(out)
    patches = procedural_patches(n_recordings, per_recording, size, seed)
    n = len(patches)
    save_patch_set(patches, out, np.arange(n), np.zeros((n, 2), dtype=np.int64))
    manifest = {
        "made_by": "pipeline.training.simdata.build_procedural_dataset",
        "n_recordings": n_recordings,
        "per_recording": per_recording,
        "patch_size": size,
        "seed": seed,
        "negative_kinds": list(NEGATIVE_KINDS),
        "n_flash": int(patches.labels.sum()),
        "n_background": int((patches.labels == 0).sum()),
    }
    (out / SYNTH_MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest
