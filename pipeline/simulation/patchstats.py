"""Flash patch statistics, to check simulated flashes against real ones.

Measured on RGB patches whose brightest pixel is at the centre (the layout of the real
labelled sets in ``../shared/data``):

- ``contrast``: green at the centre minus the median green of the patch's border
  (3-pixel frame): the flash's peak above the background, grey levels;
- ``area``: pixels of the 4-connected region around the centre whose green rises at
  least half the contrast above the background (blob size at half maximum);
- ``g_over_r``, ``b_over_g``: colour ratios of the raw values at the centre pixel;
- ``background``: that median border green;
- ``background_sd``: the standard deviation of the border's green (grain as recorded);
- ``flat_share``: the share of horizontally adjacent border pixels of equal green. An
  encoder starved of bits (or a camera's noise reduction) flattens a dark sky into
  runs of one value: real GoPro 360 backgrounds hold ~0.86, independent grain of
  σ 2 about 0.14 (``1 / (2 √π σ)``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from pipeline.patches import extract_patches
from pipeline.simulation.truth import GroundTruth
from pipeline.video import iter_frames, probe_video

BORDER_PX = 3
STATS = ("contrast", "area", "g_over_r", "b_over_g", "background", "background_sd", "flat_share")


def patch_stats(patches: NDArray[np.uint8]) -> dict[str, NDArray[np.float64]]:
    """Per patch (N, S, S, 3) RGB: contrast, half-maximum area, colour ratios at the
    centre, and the border's background level, deviation and flatness (module
    docstring)."""
    rgb = np.asarray(patches, dtype=np.float64)
    n, size = rgb.shape[:2]
    c = size // 2
    ring = np.ones((size, size), dtype=bool)
    ring[BORDER_PX:-BORDER_PX, BORDER_PX:-BORDER_PX] = False
    border = rgb[:, ring, 1]
    background = np.median(border, axis=1)
    pairs = ring[:, 1:] & ring[:, :-1]
    equal = rgb[:, :, 1:, 1] == rgb[:, :, :-1, 1]
    green = rgb[..., 1] - background[:, None, None]
    contrast = green[:, c, c]
    above = green >= 0.5 * contrast[:, None, None]
    area = np.zeros(n)
    for i in range(n):  # labelling is per patch; a few thousand patches at most
        if contrast[i] <= 0:
            continue
        labels, _ = ndimage.label(above[i])
        area[i] = np.sum(labels == labels[c, c])
    centre = rgb[:, c, c, :]
    return {
        "contrast": contrast,
        "area": area,
        "g_over_r": centre[:, 1] / np.maximum(centre[:, 0], 1.0),
        "b_over_g": centre[:, 2] / np.maximum(centre[:, 1], 1.0),
        "background": background,
        "background_sd": border.std(axis=1),
        "flat_share": equal[:, pairs].mean(axis=1),
    }


def simulated_flash_patches(
    recording: Path,
    truth: GroundTruth,
    camera: int = 1,
    size: int = 33,
    min_snr: float = 5.0,
    isolation_px: float = 10.0,
    search_px: int = 2,
) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """RGB patches of a simulated recording's decoded video, centred like the real sets
    on the brightest pixel within ``search_px`` of each visible flash-frame with peak
    SNR ≥ ``min_snr`` and no other flash within ``isolation_px``.

    Returns the patches (N, size, size, 3) and the truth rows they show.
    """
    f = truth.flashes
    frame, u, v, visible = f.in_camera(camera)
    snr = f.camera_column("snr", camera)
    rows = np.flatnonzero(visible & (snr >= min_snr))
    keep = []
    for i in rows:  # isolation: a few thousand rows, vectorised per frame would not pay
        same = visible & (frame == frame[i])
        du = (u[same] - u[i] + truth.width / 2) % truth.width - truth.width / 2
        keep.append(np.sum(np.hypot(du, v[same] - v[i]) < isolation_px) == 1)
    rows = rows[np.asarray(keep, dtype=bool)] if len(rows) else rows
    rows = rows[np.argsort(frame[rows], kind="stable")]
    names = truth.extra.get(f"cam{camera}", [f"cam{camera}_00.mp4"])
    info = probe_video([recording / name for name in names])
    patches = []
    wanted = iter(rows.tolist())
    current = next(wanted, None)
    for decoded in iter_frames(info, 0, int(frame[rows].max()) + 1 if len(rows) else 0):
        while current is not None and frame[current] == decoded.index:
            offsets = np.arange(-search_px, search_px + 1)
            cols = np.mod(round(float(u[current])) + offsets, truth.width)
            rr = np.clip(round(float(v[current])) + offsets, 0, truth.height - 1)
            window = decoded.y[np.ix_(rr, cols)]
            r, q = np.unravel_index(int(np.argmax(window)), window.shape)
            patches.append(extract_patches(decoded, [cols[q]], [rr[r]], size)[0])
            current = next(wanted, None)
    if not patches:
        return np.zeros((0, size, size, 3), np.uint8), rows[:0]
    return np.stack(patches), rows
