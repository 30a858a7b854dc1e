"""Light an earlier frame explains once shifted: a moved light, or a new one.

Sky seen through a hole in swaying leaves, or a glint on a leaf, is light that was
already there a moment ago a few pixels away; a flash is light that was not. For each
candidate we take the window around its peak in the current frame and find the shift
(up to `SHIFT_PX` of the recording) of an earlier frame that best reproduces it (least
squared difference, both smoothed by the matched filter's Gaussian), at lags `LAGS_S`:

* the *unexplained* share: the peak's light that the best-shifted earlier window does
  not account for, over the peak's contrast with the window's border: about 1 for a
  light that appeared, about 0 for one that moved (or stayed: a flash in its later
  frames is explained by itself at no shift, which the light curve already says);
* the *shift gain*: the best shift's squared difference over the unshifted one's (each
  plus half a grey level squared a pixel): 1 where the scene is still, below 1 where it
  moved (swaying foliage), the less the more of the window the motion explains.

A flash in front of swaying leaves has a gain below 1 and an unexplained share near 1;
the leaves' own light has both low. The dark hollow a moved light leaves
(`pipeline.hollow`) says the second without the shift; this says what the shift cannot
explain. Measured on the tuning nights (docs/detection.md, "Light a shifted earlier frame
explains").
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from pipeline.blobs import smooth_windows, smoothing_window, window_indices
from pipeline.noise import SAMPLE_EVERY
from pipeline.recurrence import BrightHistory

#: The earlier frames each candidate is matched against, seconds before it (2 and 8
#: frames at 30 fps): the frame just before, and one before most flashes rose.
LAGS_S = (0.067, 0.267)
#: The largest shift searched, pixels of the recording (the sway of foliage in a frame
#: or a quarter of a second, simulated 1–6 px).
SHIFT_PX = 6.0


def shifted_match(
    image: NDArray[np.uint8],
    k: int,
    history: BrightHistory,
    fps: float,
    idx: NDArray[np.intp],
    shift_px: int,
    sigma: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """How much of each candidate's light the best-shifted earlier frames explain.

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
    shift_px : int
        Largest shift searched along each axis, pixels of `image`.
    sigma : float
        The matched filter's σ, pixels of `image`; the window's half side is
        ``ceil(3 σ) + 1``.

    Returns
    -------
    unexplained, gain : ndarray of float64, shape (N, len(LAGS_S))
        Per lag: the share of the peak's contrast (its smoothed luminance minus the
        median of the window's border) that the best-shifted earlier window leaves,
        clipped to [−3, 3]; and the best shift's sum of squared differences over the
        unshifted one's (each plus ``0.25`` grey level² a pixel), in (0, 1]. NaN where
        the history holds no frame of that lag (the start of a video). Columns wrap at
        the 360° seam, rows stop at the poles.
    """
    n = len(idx)
    unexplained = np.full((n, len(LAGS_S)), np.nan)
    gain = np.full((n, len(LAGS_S)), np.nan)
    if n == 0:
        return unexplained, gain
    radius = math.ceil(3 * sigma) + 1
    here, here_band = smoothing_window(radius, sigma)
    searched, searched_band = smoothing_window(radius + shift_px, sigma)
    current = smooth_windows(image.ravel()[window_indices(image.shape, idx, here)], here_band)
    centre = current[:, radius, radius]
    border = np.concatenate(
        [current[:, 0], current[:, -1], current[:, 1:-1, 0], current[:, 1:-1, -1]], axis=1
    )
    contrast = np.maximum(centre - np.median(border, axis=1), np.float32(1e-3))
    pixels = window_indices(image.shape, idx, searched)
    size = 2 * radius + 1
    still = shift_px * (2 * shift_px + 1) + shift_px  # the unshifted position, raster order
    rows = np.arange(n)
    # Differences under half a grey level a pixel do not count: a window the encoder
    # copied from the frame before is still, not moved by 0.
    floor = np.float32(0.25 * size**2)
    for column, lag_s in enumerate(LAGS_S):
        lag = max(1, round(lag_s * fps))
        # The one kept frame of lag `lag` or just over (the history keeps every other).
        past = history.mean_before(k, (lag, lag + SAMPLE_EVERY - 1), pixels)
        if past is None:
            continue
        before = smooth_windows(past, searched_band)
        windows = sliding_window_view(before, (size, size), axis=(1, 2))
        sq = np.square(windows - current[:, None, None]).sum(axis=(3, 4)).reshape(n, -1)
        best = np.argmin(sq, axis=1)
        dr, dc = np.divmod(best, 2 * shift_px + 1)
        explained = before[rows, dr + radius, dc + radius]
        unexplained[:, column] = np.clip((centre - explained) / contrast, -3.0, 3.0)
        gain[:, column] = (sq[rows, best] + floor) / (sq[:, still] + floor)
    return unexplained, gain
