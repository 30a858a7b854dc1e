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
