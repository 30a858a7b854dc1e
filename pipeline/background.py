"""Background models of the luminance plane, and the lanes that make tracking chunkable.

A *lane* is one background model and the running noise estimate (`pipeline.noise`)
measured against it. Tracking a frame uses the lane responsible for it; every lane is
started at a frame fixed by a global grid, so a frame range tracked on its own sees
exactly the lanes of an unchunked run (see `pipeline.tracking`).

Models (`TrackingParams.background`)
------------------------------------
``"ewma"`` (default)
    Exponentially weighted mean with time constant ``τ``: ``B_{k+1} = B_k + α (Y_k −
    B_k)``, ``α = 1 − exp(−1 / (τ · fps))``. A new model starts as the running mean of
    its first frames (``α_n = max(α, 1/n)``), which settles within about ``τ``. It is
    restarted on a grid of blocks: block ``j`` (frames ``[jB, (j+1)B)``) is analysed by
    a lane started at ``max(0, jB − Wu)``; during the last ``Wu`` frames of a block the
    next block's lane warms up alongside.
``"box"``
    The mean of the ``L = τ · fps`` frames before ``k``, from integer sums (exact
    whatever frame it is started on). One lane; its noise window needs another ``L``
    frames (sampled every other frame), so a range decodes ``2L + 2`` frames before its
    start (`frames_read`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from pipeline.chunking import block_grid, box_length
from pipeline.noise import SAMPLE_EVERY, TileNoise
from pipeline.params import TrackingParams


class BackgroundModel(Protocol):
    def foreground(
        self, y: NDArray[np.uint8], out: NDArray[np.float32] | None = None
    ) -> NDArray[np.float32] | None:
        """``Y − B`` in grey levels (float32, signed; into `out` when given), or None
        before any frame."""
        ...

    def level(self) -> NDArray[np.float32]:
        """The background ``B`` in grey levels (float32)."""
        ...

    def update(self, y: NDArray[np.uint8], lit: NDArray[np.bool_] | None = None) -> None:
        """Fold a frame into the model; `lit` pixels (a flash) more slowly where the model
        supports it (`Ewma`)."""
        ...


class Ewma:
    """One EWMA image, started as a running mean.

    Pixels given as lit in an update are folded in at ``lit_share`` of the rate: a swarm
    flashing at the same spots every half second would otherwise lift the background
    there, and the negative-side noise estimate with it, by a share of its own light.
    Not while the model is still the running mean of its first frames: that mean's own
    grain lights many pixels of the next frame, and learnt at a share it would stay in
    the background for seconds (on a 4K bench recording, 56 -> 85 candidates a frame).
    """

    def __init__(self, shape: tuple[int, int], alpha: float, lit_share: float = 1.0) -> None:
        self.mean = np.zeros(shape, np.float32)
        self.n = 0
        self._alpha = alpha
        self._lit_share = lit_share

    def foreground(
        self, y: NDArray[np.uint8], out: NDArray[np.float32] | None = None
    ) -> NDArray[np.float32] | None:
        if self.n == 0:
            return None
        return np.asarray(cv2.subtract(y, self.mean, dst=out, dtype=cv2.CV_32F), np.float32)

    def level(self) -> NDArray[np.float32]:
        return self.mean

    def update(self, y: NDArray[np.uint8], lit: NDArray[np.bool_] | None = None) -> None:
        self.n += 1
        alpha = max(self._alpha, 1.0 / self.n)
        if lit is None or self._lit_share == 1.0 or alpha > self._alpha:
            cv2.accumulateWeighted(y, self.mean, alpha)
            return
        cv2.accumulateWeighted(y, self.mean, alpha, mask=np.logical_not(lit).view(np.uint8))
        cv2.accumulateWeighted(y, self.mean, alpha * self._lit_share, mask=lit.view(np.uint8))


class BoxMean:
    """Mean of the last `length` frames, from an integer running sum."""

    def __init__(self, shape: tuple[int, int], length: int) -> None:
        self._ring = np.empty((length, *shape), np.uint8)
        self._sum = np.zeros(shape, np.uint16 if length * 255 <= 0xFFFF else np.int32)
        self._n = 0
        self._next = 0

    def foreground(
        self, y: NDArray[np.uint8], out: NDArray[np.float32] | None = None
    ) -> NDArray[np.float32] | None:
        if self._n == 0:
            return None
        scaled = cv2.addWeighted(y, 1.0, self._sum, -1.0 / self._n, 0.0, dst=out, dtype=cv2.CV_32F)
        return np.asarray(scaled, np.float32)

    def level(self) -> NDArray[np.float32]:
        return (self._sum * np.float32(1.0 / max(self._n, 1))).astype(np.float32)

    def update(self, y: NDArray[np.uint8], lit: NDArray[np.bool_] | None = None) -> None:
        # Every frame counts alike: the ring's integer sums stay exact (`lit` unsupported,
        # TrackingParams forbids it with this model).
        if self._n == len(self._ring):
            np.subtract(self._sum, self._ring[self._next], out=self._sum)
        else:
            self._n += 1
        np.add(self._sum, y, out=self._sum)
        self._ring[self._next] = y
        self._next = (self._next + 1) % len(self._ring)


@dataclass
class Lane:
    """A background model and the noise of the foreground measured against it."""

    background: BackgroundModel
    noise: TileNoise


class Lanes:
    """The lanes alive at each frame, started on a global grid (exact chunking)."""

    def __init__(
        self,
        shape: tuple[int, int],
        noise_shape: tuple[int, int],
        fps: float,
        params: TrackingParams,
        start: int,
    ) -> None:
        self._shape = shape
        self._noise_shape = noise_shape
        self._window = box_length(fps, params)
        if params.background == "box":
            self._block = self._warmup = 0
            self._single = self._new_lane(BoxMean(shape, self._window))
        else:
            self._alpha = 1.0 - math.exp(-1.0 / (params.tau_s * fps))
            self._lit_share = params.lit_update_rate
            self._block, self._warmup = block_grid(fps, params)
            self._first_block = start // self._block
        self._lanes: dict[int, Lane] = {}

    def at(self, k: int) -> Iterator[tuple[Lane, bool]]:
        """Lanes that see frame `k`, each with whether it is the one that tracks it."""
        if self._block == 0:
            yield self._single, True
            return
        current = k // self._block
        for old in [j for j in self._lanes if j < current]:
            del self._lanes[old]
        for j in (current, current + 1):
            if j >= self._first_block and k >= j * self._block - self._warmup:
                if j not in self._lanes:
                    self._lanes[j] = self._new_lane(Ewma(self._shape, self._alpha, self._lit_share))
                yield self._lanes[j], j == current

    def _new_lane(self, background: BackgroundModel) -> Lane:
        return Lane(background, TileNoise(self._noise_shape, -(-self._window // SAMPLE_EVERY)))
