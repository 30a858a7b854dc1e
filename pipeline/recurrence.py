"""How often a candidate's spot has been as bright as now, in the seconds before.

Sky seen through a hole in swaying leaves, or a leaf edge catching a lamp, lights the
same pixels again and again as the foliage swings; a firefly passes. For each candidate
we take the brightest pixel of the 3 × 3 neighbourhood of its position, now and in each
of the frames ``after_s`` to ``window_s`` before it, and report the fraction of those
frames that were within ``margin`` grey levels as bright as now. A flash lasting a few
frames is not in its own window (``after_s`` is longer than a flash), and a firefly that
flashed at the same spot a second ago lights it for a few frames of the window, not a
quarter of them. Comparing neighbourhood with neighbourhood at the candidate's position
rejected fewer true flashes on the tuning nights (0–0.8 %) than comparing its brightest
pixel with that pixel's past neighbourhood (0.5–4.2 %). A flash dimmer than a static
light right beside it cannot be told apart this way and is taken as recurrent.

Measured on simulated nights (tuning seeds, 640 px; see docs/detection.md): of the
accepted candidates that are not flashes, about half in wind had their spot as bright
for a quarter of the 0.5–3 s before; of the true flashes, under 1 %.

The frames are kept at the tracking resolution (binned), every `SAMPLE_EVERY`-th one
(global frame index), so a frame range tracked on its own sees exactly the samples of
an unchunked run once its warm-up covers ``window_s``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pipeline.blobs import window_indices
from pipeline.noise import SAMPLE_EVERY

#: Fewer past samples than this in the window (the start of a video): no measurement.
MIN_SAMPLES = 4

_NEIGHBOURS = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])


class BrightHistory:
    """Past luminance frames, and the recurrence of a spot's brightness in them.

    Parameters
    ----------
    shape : (int, int)
        Rows and columns of the (binned) luminance frames.
    fps : float
        Frames per second.
    after_s, window_s : float
        The window of past frames looked at: from ``window_s`` to ``after_s`` seconds
        before the candidate's frame.
    margin : float
        Grey levels below the candidate's brightness that still count as as bright.
    """

    def __init__(
        self, shape: tuple[int, int], fps: float, after_s: float, window_s: float, margin: float
    ) -> None:
        self._first_lag = max(1, round(after_s * fps))
        self._last_lag = max(self._first_lag, round(window_s * fps))
        slots = self._last_lag // SAMPLE_EVERY + 1
        self._frames = np.zeros((slots, *shape), np.uint8)
        self._index = np.full(slots, -1, np.int64)
        self._margin = margin

    def add(self, k: int, image: NDArray[np.uint8]) -> None:
        """Keep frame `k` (every `SAMPLE_EVERY`-th global frame only)."""
        if k % SAMPLE_EVERY == 0:
            slot = (k // SAMPLE_EVERY) % len(self._index)
            self._frames[slot] = image
            self._index[slot] = k

    def mean_before(
        self, k: int, lags: tuple[int, int], pixels: NDArray[np.intp]
    ) -> NDArray[np.float32] | None:
        """Mean luminance of the kept frames ``lags[0]`` to ``lags[1]`` before frame `k`
        at `pixels`.

        Parameters
        ----------
        k : int
            Global index of the current frame.
        lags : (int, int)
            Nearest and farthest lag, frames (within the history's ``window_s``).
        pixels : ndarray of int, shape (N, P)
            Flat indices in the (binned) frame (`pipeline.blobs.window_indices`).

        Returns
        -------
        ndarray of float32, shape (N, P), or None
            None when no frame of those lags is kept (the start of a video).
        """
        lag = k - self._index
        slots = np.flatnonzero((self._index >= 0) & (lag >= lags[0]) & (lag <= lags[1]))
        if len(slots) == 0:
            return None
        past = self._frames.reshape(len(self._index), -1)[slots[:, None], pixels.ravel()]
        return past.mean(axis=0, dtype=np.float32).reshape(pixels.shape)

    def recurrence(
        self, k: int, image: NDArray[np.uint8], rows: NDArray[np.intp], cols: NDArray[np.intp]
    ) -> NDArray[np.float32]:
        """Fraction of the window's past frames in which each spot was as bright as now.

        Parameters
        ----------
        k : int
            Global index of the current frame.
        image : ndarray of uint8, shape (H, W)
            The current (binned) luminance frame.
        rows, cols : ndarray of int, shape (N,)
            Each candidate's pixel in `image`.

        Returns
        -------
        ndarray of float32, shape (N,)
            In [0, 1]: the share of past frames whose brightest pixel in the 3 × 3
            neighbourhood (columns wrapping at the 360° seam) reached the current one's
            minus the margin. NaN with fewer than `MIN_SAMPLES` past frames.
        """
        lag = k - self._index
        slots = np.flatnonzero(
            (self._index >= 0) & (lag >= self._first_lag) & (lag <= self._last_lag)
        )
        if len(slots) < MIN_SAMPLES:
            return np.full(len(rows), np.nan, np.float32)
        pixels = window_indices(image.shape, rows * image.shape[1] + cols, _NEIGHBOURS)
        # One flat gather: fancy indexing of three axes of the history costs 3 times more.
        past = self._frames.reshape(len(self._index), -1)[slots[:, None], pixels.ravel()]
        past = past.reshape(len(slots), len(rows), len(_NEIGHBOURS)).max(axis=2)  # (S, N)
        level = image.ravel()[pixels].max(axis=1).astype(np.float32) - np.float32(self._margin)
        return np.asarray((past >= level).mean(axis=0), np.float32)
