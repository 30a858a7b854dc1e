"""Flash candidates: adaptive background subtraction on the luminance plane.

For every frame ``k`` of a camera, with luminance ``Y_k`` (0–255):

1. foreground ``F_k = Y_k − B_k`` clipped at 0, where the background ``B_k`` is built
   from frames before ``k`` only (so a flash does not dim itself);
2. candidate pixels ``F_k > threshold · 255``;
3. 8-connected blobs of candidate pixels, the 360° seam included (column ``W − 1``
   touches column 0);
4. per blob: the foreground-weighted centroid ``(x, y) = (u, v)`` in pixels (pixel
   centres at integers, ``x`` wrapped into ``[0, W)``), its area, its peak foreground
   and its brightest luminance pixel (``peak_x``, ``peak_y``: where its classifier
   patch is centred);
5. optionally, the flash probability of an RGB patch around that brightest pixel.

Background models (`TrackingParams.background`)
-----------------------------------------------
``"ewma"`` (default)
    Exponentially weighted mean with time constant ``τ``: ``B_{k+1} = B_k + α (Y_k −
    B_k)``, ``α = 1 − exp(−1 / (τ · fps))``. A new model starts as the running mean of
    its first frames (``α_n = max(α, 1/n)``), which settles within about ``τ``.
``"box"``
    The paper's sliding box: the mean of the ``L = τ · fps`` frames before ``k``, from
    integer sums (exact whatever frame it is started on).

Exact chunking
--------------
Tracking a frame range ``[a, b)`` on its own must give exactly the rows of an
unchunked run. An EWMA depends on all its past, so the ``"ewma"`` model restarts on a
fixed global grid: block ``j`` (frames ``[jB, (j+1)B)``, ``B = block_s · fps``) is
always analysed by a model started at frame ``max(0, jB − Wu)`` (``Wu = warmup_tau ·
τ · fps``), in chunked and unchunked runs alike; during the last ``Wu`` frames of a
block the next block's model warms up alongside. Any range is then exact by
construction. Cost: a second EWMA update on ``Wu/B`` of the frames (20 % at the
defaults, ~0.3 ms per 4K frame) and, per independently tracked range, ``Wu`` extra
decoded frames (6 s at the defaults; `chunk_ranges` aligns ranges on the grid so a
60 s chunk decodes 66 s). The ``"box"`` model needs the ``L`` frames before ``a``
instead (memory: ``L`` luminance frames, 0.9 GB at 5.6K and τ = 2 s). `frames_read`
tells which frames a range decodes.

Cost per frame
--------------
Fireflies light a few hundred of a frame's millions of pixels, so only three
full-frame passes are made (OpenCV/numpy, vectorised): the EWMA update
(``cv2.accumulateWeighted``, float32), a uint8 comparison against a threshold level
(recomputed every 4 frames with a margin that provably keeps it below ``B + T``), and
``flatnonzero`` on the boolean mask. Everything after that (the exact float threshold,
labelling as a sparse graph of the candidate pixels with `scipy.sparse.csgraph`,
centroids) touches the candidate pixels only: about 5 ms per 3840×1920 frame on one
core. Candidates are classified in batches of `CLASSIFY_BATCH` patches gathered across
frames.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from pipeline.chunking import block_grid, box_length, frames_read
from pipeline.detections import Detections
from pipeline.params import TrackingParams
from pipeline.patches import extract_patches
from pipeline.video import Frame, VideoInfo, iter_frames

logger = logging.getLogger(__name__)

# Background images: float32 EWMA means or integer box sums.
_Image = NDArray[np.float32] | NDArray[np.uint16] | NDArray[np.int32]

#: Patches accumulated across frames before one classifier call.
CLASSIFY_BATCH = 512

#: Frames between two progress callbacks.
PROGRESS_EVERY = 32

# Frames an EWMA's coarse threshold level is reused for (see _Ewma.coarse_level).
_LEVEL_REUSE = 4

# Neighbours after a pixel in raster order (8-connectivity): right, then the row below.
_FORWARD_NEIGHBOURS = ((0, 1), (1, -1), (1, 0), (1, 1))


DEFAULT_PARAMS = TrackingParams()


class PatchClassifier(Protocol):
    """What `track` needs from a flash classifier (`pipeline.classify.FlashClassifier`)."""

    @property
    def input_size(self) -> int:
        """Side of the square RGB patches it takes, in pixels."""
        ...

    def predict(self, patches: NDArray[np.uint8]) -> NDArray[np.float32]:
        """Flash probability, shape (N,), of uint8 RGB patches of shape (N, S, S, 3)."""
        ...


@dataclass(frozen=True)
class TrackingStats:
    """What one tracking run saw and dropped.

    Attributes
    ----------
    frames : int
        Frames analysed (the requested range).
    warmup_frames : int
        Extra frames decoded before the range to warm the background model.
    candidates : int
        Rows returned.
    dropped_by_area : int
        Blobs outside ``[min_area, max_area]``.
    dropped_over_cap : int
        Blobs beyond ``max_candidates_per_frame``.
    flooded_frames : int
        Frames with more than ``max_foreground_px`` candidate pixels.
    """

    frames: int
    warmup_frames: int
    candidates: int
    dropped_by_area: int
    dropped_over_cap: int
    flooded_frames: int


@dataclass(frozen=True)
class TrackingResult:
    """Candidates of a tracked range and what was dropped on the way."""

    detections: Detections
    stats: TrackingStats


def track(
    info: VideoInfo,
    start: int = 0,
    stop: int | None = None,
    params: TrackingParams = DEFAULT_PARAMS,
    classifier: PatchClassifier | None = None,
    progress: Callable[[int], None] | None = None,
) -> Detections:
    """Find flash candidates in frames ``[start, stop)`` of one camera.

    See the module docstring for the method. The result equals, row for row and bit
    for bit, the rows with ``start <= frame < stop`` of a run over the whole video.

    Parameters
    ----------
    info : VideoInfo
        Probe result of the camera (`pipeline.video.probe_video`).
    start, stop : int
        Global frame range to report; ``stop=None`` means to the end. The background
        model is warmed on frames before ``start`` (see `frames_read`).
    params : TrackingParams
        Thresholds and background model.
    classifier : PatchClassifier, optional
        If given, every candidate's RGB patch of ``classifier.input_size`` pixels,
        centred on its brightest pixel, is classified (in batches across frames).
    progress : callable, optional
        Called with the number of frames of the range done since its previous call.

    Returns
    -------
    Detections
        Every candidate blob (no probability cut), ordered by frame, then by the raster
        position of the blob's first pixel; ``flash_probability`` is NaN without a
        classifier.
    """
    return track_with_stats(info, start, stop, params, classifier, progress).detections


def track_with_stats(
    info: VideoInfo,
    start: int = 0,
    stop: int | None = None,
    params: TrackingParams = DEFAULT_PARAMS,
    classifier: PatchClassifier | None = None,
    progress: Callable[[int], None] | None = None,
) -> TrackingResult:
    """`track`, also returning what was dropped (`TrackingStats`)."""
    stop = info.checked_range(start, stop)
    first, _ = frames_read(start, stop, info.fps, params)
    detector = _FrameDetector(info, params, start)
    scorer = _PatchScorer(classifier)
    rows = _RowCollector()
    counter = _ProgressCounter(progress)
    for frame in iter_frames(info, first, stop):
        blobs = detector.process(frame)
        if blobs is None:
            continue
        rows.add(frame.index, blobs)
        scorer.add(frame, blobs)
        counter.step()
    counter.finish()
    detections = rows.result()
    if classifier is not None:
        detections = detections.with_probability(scorer.result())
    stats = detector.stats(stop - start, start - first, len(detections))
    if stats.dropped_over_cap or stats.flooded_frames:
        logger.warning(
            "frames [%d, %d): %d blobs dropped over the per-frame cap, %d flooded frames",
            start,
            stop,
            stats.dropped_over_cap,
            stats.flooded_frames,
        )
    return TrackingResult(detections, stats)


# -- background models ---------------------------------------------------------------


class _Background(Protocol):
    def reference(self, k: int) -> tuple[_Image, float] | None:
        """Background of frame `k` as ``(image, scale)``: ``B_k = image · scale``."""
        ...

    def coarse_level(self, k: int, threshold: float) -> NDArray[np.uint8]:
        """A uint8 image ``L`` with ``Y > L`` wherever ``Y − B_k > threshold``."""
        ...

    def update(self, k: int, y: NDArray[np.uint8]) -> None:
        """Fold frame `k` into the model."""
        ...


def _level_from(
    image: _Image, scale: float, threshold: float, out: NDArray[np.uint8]
) -> NDArray[np.uint8]:
    """``round(image · scale + threshold − 1)`` saturated to uint8: for integer ``Y``,
    ``Y > image · scale + threshold`` implies ``Y > level`` (half a grey level to spare)."""
    cv2.convertScaleAbs(image, out, scale, threshold - 1.0)
    return out


class _Ewma:
    """One EWMA image, started as a running mean."""

    def __init__(self, shape: tuple[int, int], alpha: float) -> None:
        self.mean = np.zeros(shape, np.float32)
        self.n = 0
        self._alpha = alpha
        self._level = np.empty(shape, np.uint8)
        self._level_n = -_LEVEL_REUSE
        self._level_reuse = 1

    def update(self, y: NDArray[np.uint8]) -> None:
        self.n += 1
        cv2.accumulateWeighted(y, self.mean, max(self._alpha, 1.0 / self.n))

    def coarse_level(self, threshold: float) -> NDArray[np.uint8]:
        # Each update keeps at least (1 − α) of the mean (frames are ≥ 0), so a level
        # from the mean scaled by (1 − α)^(m−1) stays below it for m − 1 more updates:
        # recomputed every m = _LEVEL_REUSE frames, once the running-mean start is over.
        if self.n - self._level_n >= self._level_reuse:
            steady = 1.0 / (self.n + 1) <= self._alpha
            self._level_reuse = _LEVEL_REUSE if steady else 1
            decay = (1.0 - self._alpha) ** (self._level_reuse - 1)
            _level_from(self.mean, decay, threshold, self._level)
            self._level_n = self.n
        return self._level


class _BlockEwma:
    """EWMA restarted on a global block grid (exact chunking; module docstring)."""

    def __init__(self, shape: tuple[int, int], fps: float, params: TrackingParams, start: int):
        self._shape = shape
        self._alpha = 1.0 - math.exp(-1.0 / (params.tau_s * fps))
        self._block, self._warmup = block_grid(fps, params)
        self._first_block = start // self._block
        self._models: dict[int, _Ewma] = {}

    def reference(self, k: int) -> tuple[_Image, float] | None:
        model = self._models.get(k // self._block)
        return None if model is None or model.n == 0 else (model.mean, 1.0)

    def coarse_level(self, k: int, threshold: float) -> NDArray[np.uint8]:
        return self._models[k // self._block].coarse_level(threshold)

    def update(self, k: int, y: NDArray[np.uint8]) -> None:
        current = k // self._block
        for old in [j for j in self._models if j < current]:
            del self._models[old]
        for j in (current, current + 1):
            if j >= self._first_block and k >= j * self._block - self._warmup:
                if j not in self._models:
                    self._models[j] = _Ewma(self._shape, self._alpha)
                self._models[j].update(y)


class _BoxMean:
    """Mean of the last `length` frames, from an integer running sum."""

    def __init__(self, shape: tuple[int, int], length: int):
        self._ring = np.empty((length, *shape), np.uint8)
        self._sum = np.zeros(shape, np.uint16 if length * 255 <= 0xFFFF else np.int32)
        self._n = 0
        self._next = 0
        self._level = np.empty(shape, np.uint8)

    def reference(self, k: int) -> tuple[_Image, float] | None:
        return None if self._n == 0 else (self._sum, 1.0 / self._n)

    def coarse_level(self, k: int, threshold: float) -> NDArray[np.uint8]:
        return _level_from(self._sum, 1.0 / self._n, threshold, self._level)

    def update(self, k: int, y: NDArray[np.uint8]) -> None:
        if self._n == len(self._ring):
            np.subtract(self._sum, self._ring[self._next], out=self._sum)
        else:
            self._n += 1
        np.add(self._sum, y, out=self._sum)
        self._ring[self._next] = y
        self._next = (self._next + 1) % len(self._ring)


def _make_background(info: VideoInfo, params: TrackingParams, start: int) -> _Background:
    shape = (info.height, info.width)
    if params.background == "box":
        return _BoxMean(shape, box_length(info.fps, params))
    return _BlockEwma(shape, info.fps, params, start)


# -- per-frame detection --------------------------------------------------------------


@dataclass(frozen=True)
class _Blobs:
    """Blobs of one frame (columns of equal length)."""

    x: NDArray[np.float64]
    y: NDArray[np.float64]
    area: NDArray[np.intp]
    peak: NDArray[np.float64]
    peak_x: NDArray[np.intp]
    peak_y: NDArray[np.intp]

    def __len__(self) -> int:
        return len(self.x)

    @classmethod
    def empty(cls) -> _Blobs:
        none_f, none_i = np.zeros(0), np.zeros(0, np.intp)
        return cls(x=none_f, y=none_f, area=none_i, peak=none_f, peak_x=none_i, peak_y=none_i)

    def select(self, rows: NDArray[np.intp]) -> _Blobs:
        return _Blobs(
            x=self.x[rows],
            y=self.y[rows],
            area=self.area[rows],
            peak=self.peak[rows],
            peak_x=self.peak_x[rows],
            peak_y=self.peak_y[rows],
        )


@dataclass(frozen=True)
class _Foreground:
    """Foreground ``Y − B`` of one frame, evaluated at given pixels."""

    image: NDArray[np.uint8]
    background: _Image
    scale: float

    def at(self, idx: NDArray[np.intp]) -> NDArray[np.float64]:
        rows, cols = np.divmod(idx, self.image.shape[1])
        background = self.background[rows, cols].astype(np.float64) * self.scale
        return self.image[rows, cols] - background


class _FrameDetector:
    """Background model + thresholding + blob measurement, frame after frame."""

    def __init__(self, info: VideoInfo, params: TrackingParams, start: int):
        self._params = params
        self._start = start
        self._threshold = params.threshold * 255.0
        # A blurred spot is wider: widen the centroid window with it.
        self._ring_radius = 1 + math.ceil(params.blur_px)
        self._background = _make_background(info, params, start)
        self._mask = np.empty((info.height, info.width), np.bool_)
        self._dropped_by_area = 0
        self._dropped_over_cap = 0
        self._flooded = 0

    def process(self, frame: Frame) -> _Blobs | None:
        """Blobs of `frame`, or None for a warm-up frame before the range."""
        image = _blur(frame.y, self._params.blur_px) if self._params.blur_px > 0 else frame.y
        blobs = self._detect(frame.index, image, frame.y) if frame.index >= self._start else None
        self._background.update(frame.index, image)
        return blobs

    def stats(self, frames: int, warmup_frames: int, candidates: int) -> TrackingStats:
        return TrackingStats(
            frames=frames,
            warmup_frames=warmup_frames,
            candidates=candidates,
            dropped_by_area=self._dropped_by_area,
            dropped_over_cap=self._dropped_over_cap,
            flooded_frames=self._flooded,
        )

    def _detect(self, k: int, image: NDArray[np.uint8], luma: NDArray[np.uint8]) -> _Blobs:
        reference = self._background.reference(k)
        if reference is None:  # nothing seen yet: the frame is its own background
            return _Blobs.empty()
        foreground = _Foreground(image, *reference)
        level = self._background.coarse_level(k, self._threshold)
        idx, values = self._candidate_pixels(foreground, level)
        idx, values = self._limit_pixels(idx, values)
        blobs = _measure_blobs(idx, values, foreground, luma, self._ring_radius)
        return self._filter(blobs)

    def _candidate_pixels(
        self, foreground: _Foreground, level: NDArray[np.uint8]
    ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """Flat indices (ascending) and foreground of the pixels above the threshold."""
        # The coarse uint8 test selects a superset in one vectorised pass; the exact
        # float test then runs on those few pixels only.
        np.greater(foreground.image, level, out=self._mask)
        idx = np.flatnonzero(self._mask)  # fast on bool, slow on a uint8 mask
        values = foreground.at(idx)
        keep = values > self._threshold
        return idx[keep], values[keep]

    def _limit_pixels(
        self, idx: NDArray[np.intp], values: NDArray[np.float64]
    ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """In a flooded frame, only the brightest ``max_foreground_px`` pixels."""
        limit = self._params.max_foreground_px
        if len(idx) <= limit:
            return idx, values
        self._flooded += 1
        keep = np.sort(np.argpartition(values, len(values) - limit)[len(values) - limit :])
        return idx[keep], values[keep]

    def _filter(self, blobs: _Blobs) -> _Blobs:
        """Blobs within the area bounds, at most the brightest per-frame cap of them."""
        area_ok = (blobs.area >= self._params.min_area) & (blobs.area <= self._params.max_area)
        self._dropped_by_area += int(np.count_nonzero(~area_ok))
        kept = np.flatnonzero(area_ok)
        cap = self._params.max_candidates_per_frame
        if len(kept) > cap:
            self._dropped_over_cap += len(kept) - cap
            kept = np.sort(kept[np.argsort(-blobs.peak[kept], kind="stable")[:cap]])
        return blobs.select(kept)


def _blur(y: NDArray[np.uint8], sigma: float) -> NDArray[np.uint8]:
    """Gaussian blur that wraps around the 360° seam and replicates the pole rows."""
    pad = math.ceil(3 * sigma)
    wrapped = cv2.copyMakeBorder(y, 0, 0, pad, pad, cv2.BORDER_WRAP)
    blurred = cv2.GaussianBlur(wrapped, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
    return np.asarray(blurred[:, pad:-pad], dtype=np.uint8)


def _measure_blobs(
    idx: NDArray[np.intp],
    values: NDArray[np.float64],
    foreground: _Foreground,
    luma: NDArray[np.uint8],
    ring_radius: int,
) -> _Blobs:
    """Group candidate pixels into 8-connected blobs and measure them.

    The centroid weights the clipped foreground over the blob dilated by `ring_radius`
    pixels: the thresholded pixels alone are an asymmetric cut of the spot and bias
    the centroid toward the nearest pixel centre (by up to 0.23 px for a σ = 1 px spot;
    under 0.06 px with a one-pixel ring).

    Parameters
    ----------
    idx : ndarray of int, shape (N,)
        Ascending flat indices ``v · W + u`` of the candidate pixels of one frame.
    values : ndarray of float, shape (N,)
        Their foreground values, in grey levels.
    foreground : _Foreground
        The frame's foreground, for the pixels around the blobs.
    luma : ndarray of uint8, shape (H, W)
        The frame's luminance, for the brightest pixel.
    ring_radius : int
        Dilation of the centroid window around each blob, in pixels.

    Returns
    -------
    _Blobs
        One row per blob, in raster order of the blob's first pixel: centroid ``x``
        (wrapped into ``[0, W)``) and ``y`` in pixels, area (candidate pixels), peak
        foreground, and the brightest luminance pixel (ties: the first in raster order).
    """
    if len(idx) == 0:
        return _Blobs.empty()
    height, width = luma.shape
    labels = _label(idx, width)
    rows, cols = np.divmod(idx, width)
    order = np.lexsort((idx, -luma[rows, cols].astype(np.int16), labels))
    starts = np.flatnonzero(np.r_[True, np.diff(labels[order]) != 0])
    peak_x, peak_y = cols[order[starts]], rows[order[starts]]
    peak = np.maximum.reduceat(values[order], starts)
    area = np.bincount(labels)

    ring, ring_labels = _ring(idx, labels, width, height, ring_radius)
    all_labels = np.concatenate([labels, ring_labels])
    weight = np.concatenate([values, np.maximum(foreground.at(ring), 0.0)])
    all_rows, all_cols = np.divmod(np.concatenate([idx, ring]), width)
    # Offsets from the brightest pixel, wrapped, so a blob across the seam stays whole.
    du = (all_cols - peak_x[all_labels] + width // 2) % width - width // 2
    total = np.bincount(all_labels, weights=weight)
    x = np.mod(peak_x + np.bincount(all_labels, weights=weight * du) / total, width)
    x[x >= width] -= width  # mod can round a tiny negative up to exactly W
    y = np.bincount(all_labels, weights=weight * all_rows) / total
    return _Blobs(x=x, y=y, area=area, peak=peak, peak_x=peak_x, peak_y=peak_y)


def _ring(
    idx: NDArray[np.intp], labels: NDArray[np.int32], width: int, height: int, radius: int
) -> tuple[NDArray[np.intp], NDArray[np.int32]]:
    """Pixels within `radius` (chessboard distance) of the blobs but not in them, each
    with the label of one blob it touches."""
    rows, cols = np.divmod(idx, width)
    offsets = np.arange(-radius, radius + 1)
    dr, dc = (g.ravel()[None, :] for g in np.meshgrid(offsets, offsets, indexing="ij"))
    nr = rows[:, None] + dr
    inside = (nr >= 0) & (nr < height)
    neighbour = (nr * width + (cols[:, None] + dc) % width)[inside]
    neighbour_labels = np.broadcast_to(labels[:, None], nr.shape)[inside]
    pos = np.minimum(np.searchsorted(idx, neighbour), len(idx) - 1)
    outside = idx[pos] != neighbour
    ring, first = np.unique(neighbour[outside], return_index=True)
    return ring, neighbour_labels[outside][first]


def _label(idx: NDArray[np.intp], width: int) -> NDArray[np.int32]:
    """Connected-component labels of sparse pixels (8-connected, columns wrap).

    Labels are numbered in raster order of each component's first pixel.
    """
    rows, cols = np.divmod(idx, width)
    src, dst = [], []
    for dr, dc in _FORWARD_NEIGHBOURS:
        neighbour = (rows + dr) * width + (cols + dc) % width
        pos = np.searchsorted(idx, neighbour)
        pos[pos == len(idx)] = 0
        hit = idx[pos] == neighbour
        src.append(np.flatnonzero(hit))
        dst.append(pos[hit])
    edges_from, edges_to = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix(
        (np.ones(len(edges_from), np.int8), (edges_from, edges_to)), shape=(len(idx), len(idx))
    )
    _, labels = connected_components(graph, directed=False)
    return labels.astype(np.int32)


# -- accumulation across frames --------------------------------------------------------


class _RowCollector:
    """Per-frame blobs gathered into one table; compacted as it grows."""

    _COMPACT_EVERY = 256

    def __init__(self) -> None:
        self._parts: list[Detections] = []
        self._recent: list[Detections] = []

    def add(self, frame_index: int, blobs: _Blobs) -> None:
        if len(blobs) == 0:
            return
        self._recent.append(
            Detections.from_columns(
                np.full(len(blobs), frame_index),
                blobs.x,
                blobs.y,
                area=blobs.area,
                peak=blobs.peak,
                peak_x=blobs.peak_x,
                peak_y=blobs.peak_y,
            )
        )
        if len(self._recent) >= self._COMPACT_EVERY:
            self._parts.append(Detections.concat(self._recent))
            self._recent = []

    def result(self) -> Detections:
        return Detections.concat([*self._parts, *self._recent])


class _PatchScorer:
    """Classifies candidate patches in batches gathered across frames."""

    def __init__(self, classifier: PatchClassifier | None, batch: int = CLASSIFY_BATCH):
        self._classifier = classifier
        self._batch = batch
        self._pending: list[NDArray[np.uint8]] = []
        self._n_pending = 0
        self._scores: list[NDArray[np.float32]] = []

    def add(self, frame: Frame, blobs: _Blobs) -> None:
        if self._classifier is None or len(blobs) == 0:
            return
        patches = extract_patches(frame, blobs.peak_x, blobs.peak_y, self._classifier.input_size)
        self._pending.append(patches)
        self._n_pending += len(patches)
        if self._n_pending >= self._batch:
            self._flush()

    def result(self) -> NDArray[np.float32]:
        self._flush()
        return np.concatenate(self._scores) if self._scores else np.zeros(0, np.float32)

    def _flush(self) -> None:
        if self._classifier is None or not self._pending:
            return
        patches = np.concatenate(self._pending)
        scores = np.asarray(self._classifier.predict(patches), dtype=np.float32)
        if scores.shape != (len(patches),):
            raise ValueError(
                f"classifier returned scores of shape {scores.shape} for {len(patches)} patches"
            )
        self._scores.append(scores)
        self._pending, self._n_pending = [], 0


class _ProgressCounter:
    def __init__(self, callback: Callable[[int], None] | None):
        self._callback = callback
        self._pending = 0

    def step(self) -> None:
        self._pending += 1
        if self._pending >= PROGRESS_EVERY:
            self.finish()

    def finish(self) -> None:
        if self._callback is not None and self._pending:
            self._callback(self._pending)
        self._pending = 0
