"""Synthetic labelled patch folders for the training tests.

Flashes are small yellow-green Gaussian dots on dark noise; backgrounds are several
white glints on brighter textured foliage-like noise. Each "video" has its own
exposure, so the split and grouping logic has real groups to respect.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.training.dataset import PatchSet, save_patch_set

SIZE = 33


def synthetic_patches(n_videos: int = 4, per_class: int = 6, seed: int = 0) -> PatchSet:
    """``n_videos`` groups of ``per_class`` flashes and backgrounds each, uint8 RGB."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:SIZE, :SIZE] - SIZE // 2
    images, labels, groups = [], [], []
    for v in range(n_videos):
        exposure = rng.uniform(0.7, 1.3)
        for label in (1, 0):
            for _ in range(per_class):
                images.append(_flash(rng, yy, xx, exposure) if label else _glints(rng, yy, xx))
                labels.append(label)
                groups.append(f"vid{v}")
    return PatchSet(
        np.stack(images),
        np.array(labels, dtype=np.int8),
        np.array(groups),
        np.full(len(labels), ""),
        np.full(len(labels), "synthetic"),
    )


def _flash(rng: np.random.Generator, yy: np.ndarray, xx: np.ndarray, exposure: float) -> np.ndarray:
    dot = np.exp(-(yy**2 + xx**2) / (2 * rng.uniform(0.8, 1.5) ** 2))
    colour = np.array([200.0, 230.0, 60.0]) * exposure
    image = rng.normal(12, 3, (SIZE, SIZE, 3)) + dot[..., None] * colour
    return np.clip(image, 0, 255).astype(np.uint8)


def _glints(rng: np.random.Generator, yy: np.ndarray, xx: np.ndarray) -> np.ndarray:
    image = rng.normal(70, 25, (SIZE, SIZE, 3)).mean(axis=2, keepdims=True).repeat(3, axis=2)
    centres = np.vstack([[0, 0], rng.integers(-12, 13, (4, 2))])
    for cy, cx in centres:
        image += 150 * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / 2.0)[..., None]
    return np.clip(image, 0, 255).astype(np.uint8)


@pytest.fixture
def patch_folder(tmp_path: Path) -> Path:
    """A dataset folder (flash/, background/) of synthetic patches from 4 videos."""
    patches = synthetic_patches()
    n = len(patches)
    save_patch_set(
        patches, tmp_path / "data", np.arange(n), np.column_stack([np.arange(n), np.arange(n)])
    )
    return tmp_path / "data"
