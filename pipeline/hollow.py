"""The dark hollow a light leaves where it was: what tells a moving light from a flash.

A flash lights up from nothing: around it, the frame differs from the frames a fraction
of a second before only by noise. A headlight, a flashlight's beam or a glint on a
swaying leaf *moved*: where it was a moment ago the frame is now darker than it was, so
the difference holds a dark hollow beside the bright spot, as deep as the light is
bright. The running background (τ ≈ 2 s) smears a light's past positions over seconds
and keeps only a shallow trace of the hollow; the frames 0.1–0.4 s before keep all of
it, and a flash (2–15 frames) is mostly not yet lit in them.

The depth is measured on the difference matched-filtered like the foreground (the same
Gaussian), over the candidate's own filtered response against the running background:
about 0 for a flash, down to −1 for a light that moved by more than its size.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from numpy.typing import NDArray

from pipeline.blobs import window_indices
from pipeline.recurrence import BrightHistory

#: The frames the current one is compared with, seconds before it.
RECENT_S = (0.1, 0.4)


@functools.cache
def _geometry(radius: int, sigma: float) -> tuple[NDArray[np.intp], NDArray[np.float32]]:
    """Offsets of the window plus the filter's halo (raster order), and the banded
    matrix that filters one axis of it down to the window: ``(2r + 1, 2r + 1 + 2h)``."""
    halo = math.ceil(3 * sigma) if sigma > 0 else 0
    side = 2 * (radius + halo) + 1
    steps = np.arange(side) - radius - halo
    dr, dc = np.meshgrid(steps, steps, indexing="ij")
    offsets = np.column_stack([dr.ravel(), dc.ravel()])
    kernel = cv2.getGaussianKernel(2 * halo + 1, sigma).ravel() if halo else np.ones(1)
    band = np.zeros((2 * radius + 1, side), np.float32)
    for i in range(2 * radius + 1):
        band[i, i : i + 2 * halo + 1] = kernel
    offsets.flags.writeable = band.flags.writeable = False  # shared by every caller
    return offsets, band


def hollow_depth(
    image: NDArray[np.uint8],
    k: int,
    history: BrightHistory,
    fps: float,
    idx: NDArray[np.intp],
    response: NDArray[np.floating],
    radius: int,
    sigma: float,
) -> NDArray[np.float64]:
    """How dark the deepest spot around each candidate has become since a moment ago.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W)
        The current (binned) luminance frame `k`.
    k : int
        Its global frame index.
    history : BrightHistory
        The frames before it (`pipeline.recurrence`), at the same binning.
    fps : float
        Frames per second.
    idx : ndarray of intp, shape (N,)
        Flat indices of the candidates' peaks in `image`.
    response : ndarray of float, shape (N,)
        Their matched-filtered foreground against the running background, grey levels.
    radius : int
        Half side of the square searched around each peak, pixels of `image`.
    sigma : float
        The matched filter's σ, pixels of `image`.

    Returns
    -------
    ndarray of float64, shape (N,)
        The lowest value of ``filter(frame − mean of the frames `RECENT_S` before)``
        within `radius` of the peak, over `response`: near 0 or above for a light that
        appeared, negative for one that moved or dimmed; NaN when no earlier frame is
        kept (the first frames of a video).
    """
    n = len(idx)
    if n == 0:
        return np.zeros(0)
    lags = (max(1, round(RECENT_S[0] * fps)), max(1, round(RECENT_S[1] * fps)))
    offsets, band = _geometry(radius, sigma)
    pixels = window_indices(image.shape, idx, offsets)
    past = history.mean_before(k, lags, pixels)
    if past is None:
        return np.full(n, np.nan)
    side = band.shape[1]
    change = (image.ravel()[pixels].astype(np.float32) - past).reshape(n, side, side)
    filtered = np.einsum("ij,njk,lk->nil", band, change, band, optimize=True)
    return filtered.reshape(n, -1).min(axis=1).astype(np.float64) / np.asarray(response, np.float64)
