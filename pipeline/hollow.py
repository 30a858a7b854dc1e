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

import numpy as np
from numpy.typing import NDArray

from pipeline.blobs import smooth_windows, smoothing_window, window_indices
from pipeline.recurrence import BrightHistory

#: The frames the current one is compared with, seconds before it.
RECENT_S = (0.1, 0.4)


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
    offsets, band = smoothing_window(radius, sigma)
    pixels = window_indices(image.shape, idx, offsets)
    past = history.mean_before(k, lags, pixels)
    if past is None:
        return np.full(n, np.nan)
    filtered = smooth_windows(image.ravel()[pixels].astype(np.float32) - past, band)
    return filtered.reshape(n, -1).min(axis=1).astype(np.float64) / np.asarray(response, np.float64)
