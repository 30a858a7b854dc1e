"""Running estimate of the temporal noise of the (matched-filtered) foreground, per tile.

Thresholds in units of the noise make detection follow the sensor: a clean frame
finds flashes a few grey levels above its background, a grainy or wind-shaken one is
not flooded with candidates. The noise is measured on the *negative* half of the
filtered foreground ``F`` (frame minus background): flashes only add light, so they
cannot inflate it, while sensor grain and swaying foliage move both ways. For
zero-mean Gaussian noise of deviation ``σ``, ``E[max(−F, 0)] = σ / √(2π)``; the tile
means of ``max(−F, 0)`` of every `SAMPLE_EVERY`-th frame are averaged over a window.

The running sum is kept in integers (tile means quantised to 1/1024 grey level), so
the estimate does not depend on how many frames the window has slid over: a frame
range tracked on its own gets exactly the estimate of an unchunked run.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

_QUANTUM = 1024.0

#: Frames between two samples of the noise (global frame index multiples): the noise
#: changes over seconds, so every other frame halves the cost and loses nothing.
SAMPLE_EVERY = 2
_GAUSSIAN_SCALE = math.sqrt(2.0 * math.pi)


def tile_grid(shape: tuple[int, int], tile_px: int) -> tuple[int, int]:
    """Rows and columns of noise tiles of about `tile_px` pixels over an image `shape`."""
    height, width = shape
    return max(1, round(height / tile_px)), max(1, round(width / tile_px))


class TileNoise:
    """Noise deviation ``σ`` of the foreground per tile, over a sliding window of frames.

    Parameters
    ----------
    grid : (int, int)
        Tile rows and columns (`tile_grid`).
    window : int
        Samples averaged (the most recent ones).
    """

    def __init__(self, grid: tuple[int, int], window: int) -> None:
        self._ring = np.zeros((max(1, window), *grid), np.int64)
        self._sum = np.zeros(grid, np.int64)
        self._n = 0
        self._next = 0
        self._map: NDArray[np.float32] | None = None

    @property
    def frames(self) -> int:
        """Frames currently averaged."""
        return self._n

    def update(self, foreground: NDArray[np.float32]) -> None:
        """Add one frame's filtered foreground (grey levels, signed)."""
        rows, cols = self._sum.shape
        _, negative = cv2.threshold(foreground, 0.0, 0.0, cv2.THRESH_TOZERO_INV)  # min(F, 0)
        # INTER_AREA over a whole-image shrink averages each tile's pixels.
        means = cv2.resize(negative, (cols, rows), interpolation=cv2.INTER_AREA)
        quantised = np.rint(-means.astype(np.float64) * _QUANTUM).astype(np.int64)
        if self._n == len(self._ring):
            self._sum -= self._ring[self._next]
        else:
            self._n += 1
        self._sum += quantised
        self._ring[self._next] = quantised
        self._next = (self._next + 1) % len(self._ring)
        self._map = None

    def sigma(self) -> NDArray[np.float32]:
        """Current ``σ`` per tile in grey levels (zeros before the first frame)."""
        if self._n == 0:
            return np.zeros(self._sum.shape, np.float32)
        mean_negative = self._sum / (self._n * _QUANTUM)
        return (mean_negative * _GAUSSIAN_SCALE).astype(np.float32)

    def pixel_sigma(self, shape: tuple[int, int], floor: float) -> NDArray[np.float32]:
        """``max(σ, floor)`` of each pixel's tile over an image of `shape` (rows, columns).

        The map is rebuilt only after an `update` (every `SAMPLE_EVERY`-th frame): the
        same array is returned until then, so derived maps can be cached on it. It must
        not be modified.
        """
        if self._map is None or self._map.shape != shape:
            tiles = np.maximum(self.sigma(), np.float32(floor))
            height, width = shape
            self._map = np.asarray(
                cv2.resize(tiles, (width, height), interpolation=cv2.INTER_NEAREST)
            )
        return self._map
