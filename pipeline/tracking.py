"""Flash candidates: noise-adaptive detection of point flashes on the luminance plane.

For every frame ``k`` of a camera, with luminance ``Y_k`` (0–255):

1. ``Y_k`` averaged over ``b × b`` bins at high resolution (2 × 2 at 4K), and the
   foreground ``F_k = Y_k − B_k`` (signed), where the background ``B_k`` is built from
   frames before ``k`` only, so a flash does not dim itself (`pipeline.background`);
2. the matched filter: ``F_k`` filtered with a Gaussian the size of a point flash in
   pixels of the recording (`pipeline.matched_filter`);
3. the noise ``σ`` of the filtered foreground per tile, running over the last ``τ`` of
   frames and measured on its negative half, which flashes cannot inflate
   (`pipeline.noise`), floored per pixel at ``min_noise + relative_noise · B`` (a
   bright static light jitters more than the dark sky around it);
4. hysteresis in units of ``σ``: 8-connected blobs of the pixels above
   ``extent_threshold · σ`` (the 360° seam included: column ``W − 1`` touches column 0);
   each local maximum reaching the seed level (``threshold · σ``, higher when binned:
   `TrackingParams.seed_level`) is a candidate, and a blob holding
   several is split between them (one larger than ``max_area`` is dropped whole); the
   local maxima from ``lit_threshold · σ`` up to the seed level are kept apart as faint
   peaks (frame, position, SNR): they are no candidates and split no blob, but tell the
   acceptance stage that a spot is lit (`pipeline.acceptance.assess`);
5. per candidate: the sub-pixel position ``(x, y) = (u, v)`` of its peak, from a
   Gaussian through the filter's response (pixel centres at integers, ``x`` wrapped into
   ``[0, W)``), and at full resolution its area, its peak foreground, its SNR (largest
   filtered response in ``σ``) and its brightest luminance pixel (``peak_x``,
   ``peak_y``: where its classifier patch is centred);
6. the share of the frames 0.5–3 s before in which the neighbourhood of ``(x, y)`` was
   as bright as now (`pipeline.recurrence`): swaying foliage lights the same pixels
   again and again, a firefly passes;
7. optionally, the flash probability of an RGB patch around that brightest pixel.

Exact chunking
--------------
Tracking a frame range ``[a, b)`` on its own must give exactly the rows of an
unchunked run. The EWMA background and its noise estimate depend on their past, so
they restart on a fixed global grid (`pipeline.background.Lanes`): block ``j`` (frames
``[jB, (j+1)B)``, ``B = block_s · fps``) is always analysed by a lane started at frame
``max(0, jB − Wu)`` (``Wu = warmup_tau · τ · fps``), in chunked and unchunked runs
alike; during the last ``Wu`` frames of a block the next block's lane warms up
alongside. Any range is then exact by construction. The ``"box"`` model needs ``2L + 2``
frames before ``a`` instead (``L`` for the mean, ``L + 2`` for its noise window).
`frames_read` tells which frames a range decodes.

Cost per frame
--------------
One full-resolution pass (the binning, at 4K); then, on the binned image, the
foreground, the filter, the noise tile means (every other frame, every other row), the
threshold map, the threshold comparison and the EWMA update (OpenCV, vectorised).
Everything after that touches the candidate pixels only: their noise ``σ`` looked up by
tile, labelling as a sparse graph with `scipy.sparse.csgraph`, local maxima and
sub-pixel peaks, with neighbours found through a reused image of the pixels' list
positions (`pipeline.blobs.PixelIndex`). Candidates are classified
in batches of `CLASSIFY_BATCH` patches gathered across frames. OpenCV runs on one
thread here: the decoder's frame threads keep the cores busy. The full-frame images of
the loop (binned luminance, foreground, filtered foreground, noise scratch, threshold map) are
allocated once and reused: fresh ones cost the kernel ~1,700 page faults a frame at 4K.
At 3840 × 1920 with 39 candidates per frame: 0.69 × decode-only throughput (CPU 0.72)
with the classifier and the recurrence history (`bench/bench_tracking.py`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from pipeline.background import Lanes
from pipeline.blobs import (
    Blobs,
    PixelIndex,
    label,
    local_maxima,
    measure,
    ring_max,
    split_at_peaks,
    subpixel_peak,
    to_full_resolution,
    trough,
    upsample,
)
from pipeline.chunking import frames_read
from pipeline.crowding import CrowdedSeeds, crowded_seeds
from pipeline.detections import Detections
from pipeline.hollow import hollow_depth
from pipeline.matched_filter import bin_image, binning, matched_filter
from pipeline.noise import SAMPLE_EVERY, PixelNoise, tile_grid
from pipeline.params import TrackingParams
from pipeline.patches import extract_patches
from pipeline.recurrence import BrightHistory
from pipeline.video import Frame, VideoInfo, iter_frames

logger = logging.getLogger(__name__)

#: Patches accumulated across frames before one classifier call.
CLASSIFY_BATCH = 512

#: Frames between two progress callbacks.
PROGRESS_EVERY = 32


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
        Frames with more candidate pixels than `TrackingParams.max_foreground_px`.
    faint_peaks : int
        Faint peaks returned (between ``lit_threshold`` and ``threshold``).
    faint_over_cap : int
        Faint peaks beyond ``max_faint_peaks_per_frame``.
    """

    frames: int
    warmup_frames: int
    candidates: int
    dropped_by_area: int
    dropped_over_cap: int
    flooded_frames: int
    faint_peaks: int = 0
    faint_over_cap: int = 0


@dataclass(frozen=True)
class TrackingResult:
    """Candidates of a tracked range, its faint peaks and what was dropped on the way.

    ``faint_peaks`` are the local maxima between ``lit_threshold`` and ``threshold`` σ
    (frame, position and SNR only; never classified): too faint to be candidates, they
    still tell the acceptance stage that a spot is lit (`pipeline.acceptance.assess`).
    ``key_frames`` are the frames of the range the encoder coded whole (`Frame.key`):
    grain renewed at once makes bursts of speckle there (`pipeline.sync`).
    """

    detections: Detections
    faint_peaks: Detections
    stats: TrackingStats
    key_frames: NDArray[np.int64]


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
    rows, faint_rows = _RowCollector(), _RowCollector()
    key_frames: list[int] = []
    counter = _ProgressCounter(progress)
    with _opencv_threads(1):
        for frame in iter_frames(info, first, stop):
            found = detector.process(frame)
            if found is None:
                continue
            if frame.key:
                key_frames.append(frame.index)
            blobs, faint = found
            rows.add(_candidate_rows(frame.index, blobs, detector.recurrence(blobs)))
            faint_rows.add(_faint_rows(frame.index, faint))
            scorer.add(frame, blobs)
            counter.step()
        counter.finish()
    detections = rows.result()
    if classifier is not None:
        detections = detections.with_probability(scorer.result())
    faint_peaks = faint_rows.result()
    stats = detector.stats(stop - start, start - first, len(detections), len(faint_peaks))
    if stats.dropped_over_cap or stats.flooded_frames:
        logger.warning(
            "frames [%d, %d): %d blobs dropped over the per-frame cap, %d flooded frames",
            start,
            stop,
            stats.dropped_over_cap,
            stats.flooded_frames,
        )
    return TrackingResult(detections, faint_peaks, stats, np.array(key_frames, np.int64))


@contextmanager
def _opencv_threads(n: int) -> Iterator[None]:
    """OpenCV's thread count set to `n` for the block, then restored.

    The decoder's frame threads already keep every core busy while a frame is
    analysed; OpenCV's own pool then only spins: a second thread nearly doubles the CPU
    time of the matched filter for no gain in wall time (measured on 2 cores).
    """
    previous = cv2.getNumThreads()
    cv2.setNumThreads(n)
    try:
        yield
    finally:
        cv2.setNumThreads(previous)


# -- per-frame detection --------------------------------------------------------------

#: Share of a frame's pixels above the extent level from which it is flooded (by
#: default, `TrackingParams.max_foreground_px` None): a guard against a frame flooded by
#: light (a flashlight in the lens), scaled with the frame so that grain never reaches it.
FLOOD_SHARE = 0.25


class _FrameDetector:
    """Background lanes + matched filter + noise-scaled hysteresis, frame after frame."""

    def __init__(self, info: VideoInfo, params: TrackingParams, start: int):
        self._params = params
        self._start = start
        self._bin = binning(info.width, params.bin_px)
        if info.height % self._bin:
            raise ValueError(
                f"a {info.width}×{info.height} frame cannot be split in {self._bin}-pixel bins"
            )
        self._binned = (info.height // self._bin, info.width // self._bin)
        grid = tile_grid(self._binned, params.noise_tile_px)
        self._lanes = Lanes(self._binned, grid, info.fps, params, start)
        self._history = BrightHistory(
            self._binned,
            info.fps,
            params.recurrence_after_s,
            params.recurrence_window_s,
            params.recurrence_margin,
        )
        self._last = (-1, np.zeros(self._binned, np.uint8))  # index and binned luminance
        self._mask = np.empty(self._binned, np.bool_)
        self._slows_lit = params.lit_update_rate < 1.0
        self._lit_pixels = np.empty(self._binned, np.bool_)
        self._sigma = params.matched_sigma_px / self._bin  # in bins
        self._threshold = params.seed_level(self._bin)
        self._lit = params.lit_level(self._bin)
        radius = max(1, math.ceil(2 * self._sigma))  # of a local maximum
        self._pixels = PixelIndex(self._binned, min(radius, self._binned[1]))
        self._ring_px = max(radius + 1, math.ceil(3 * self._sigma))
        self._trough_px = max(1, round(params.trough_radius_px / self._bin))
        self._fps = info.fps
        # The foreground and its filtered image, reused by every lane and frame: a fresh
        # pair per frame costs the kernel ~2,000 page faults a frame at 4K.
        self._foreground = np.empty(self._binned, np.float32)
        self._filtered = np.empty(self._binned, np.float32)
        # Binned luminance of this frame and the last, in turn (`recurrence` reads the
        # last frame processed after `process` returns).
        self._small = np.empty((2, *self._binned), np.uint8)
        # Candidate pixels labelled per frame, in (binned) pixels analysed.
        if params.max_foreground_px is None:
            self._flood_limit = int(self._binned[0] * self._binned[1] * FLOOD_SHARE)
        else:
            self._flood_limit = max(1, params.max_foreground_px // self._bin**2)
        self._dropped_by_area = 0
        self._dropped_over_cap = 0
        self._faint_over_cap = 0
        self._flooded = 0

    def process(self, frame: Frame) -> tuple[Blobs, FaintPeaks] | None:
        """Blobs and faint peaks of `frame`, or None for a warm-up frame before the range."""
        image = _blur(frame.y, self._params.blur_px) if self._params.blur_px > 0 else frame.y
        small = bin_image(image, self._bin, self._small[frame.index % 2])
        found: tuple[Blobs, FaintPeaks] | None = None
        for lane, tracks in self._lanes.at(frame.index):
            foreground = lane.background.foreground(small, self._foreground)
            lit = None
            if foreground is not None:
                filtered = matched_filter(foreground, self._sigma, self._filtered)
                if frame.index % SAMPLE_EVERY == 0 or lane.noise.frames == 0:
                    lane.noise.update(filtered)
                detects = tracks and frame.index >= self._start
                if detects or self._slows_lit:
                    noise = lane.noise.pixel_noise(
                        self._binned, self._params.min_noise, self._params.extent_threshold
                    )
                if detects:
                    found = self._detect(
                        filtered, noise, image, lane.background.level(), small, frame.index
                    )
                if self._slows_lit:
                    # Above the extent level, as `_detect` labels (its mask, when it ran):
                    # every lane alike, so a range tracked on its own stays exact.
                    lit = (
                        self._mask
                        if detects
                        else np.greater(filtered, noise.level, out=self._lit_pixels)
                    )
            lane.background.update(small, lit)
        self._history.add(frame.index, small)
        self._last = (frame.index, small)
        if found is None and frame.index >= self._start:
            found = (Blobs.empty(), FaintPeaks.empty())  # the frame is its own background
        return found

    def recurrence(self, blobs: Blobs) -> NDArray[np.float32]:
        """`BrightHistory.recurrence` of the blobs of the last frame processed."""
        k, small = self._last
        # The binned pixel holding each blob's (full-resolution, sub-pixel) position.
        rows = np.minimum((blobs.y + 0.5) // self._bin, self._binned[0] - 1).astype(np.intp)
        cols = ((blobs.x + 0.5) // self._bin).astype(np.intp) % self._binned[1]
        return self._history.recurrence(k, small, rows, cols)

    def stats(
        self, frames: int, warmup_frames: int, candidates: int, faint_peaks: int
    ) -> TrackingStats:
        return TrackingStats(
            frames=frames,
            warmup_frames=warmup_frames,
            candidates=candidates,
            dropped_by_area=self._dropped_by_area,
            dropped_over_cap=self._dropped_over_cap,
            flooded_frames=self._flooded,
            faint_peaks=faint_peaks,
            faint_over_cap=self._faint_over_cap,
        )

    def _detect(
        self,
        filtered: NDArray[np.float32],
        noise: PixelNoise,
        luma: NDArray[np.uint8],
        background: NDArray[np.float32],
        small: NDArray[np.uint8],
        k: int,
    ) -> tuple[Blobs, FaintPeaks]:
        idx, snr = self._extent_pixels(filtered, noise, background)
        idx, snr = self._limit_pixels(idx, snr)
        labels, blob_snr, peak, (faint_idx, faint_snr), crowded = self._seeded(idx, snr, filtered)
        area = np.bincount(labels[labels >= 0], minlength=len(blob_snr)) * self._bin**2
        keep = self._filter(area, blob_snr)
        inside = np.isin(labels, keep)
        # Renumber the kept blobs 0.. in their (raster) order.
        idx, snr, labels = idx[inside], snr[inside], np.searchsorted(keep, labels[inside])
        width = self._binned[1]
        x, y = subpixel_peak(filtered, peak[keep], self._bin)
        # Seeds beside a brighter spot are placed on their own light, not its slope.
        own = np.flatnonzero(np.isin(peak[keep], crowded.idx))
        if len(own):
            at = np.searchsorted(crowded.idx, peak[keep][own])
            x[own], y[own] = to_full_resolution(crowded.row[at], crowded.col[at], width, self._bin)
        full_idx, full_labels = upsample(idx, labels, width, self._bin)
        rows, cols = np.divmod(full_idx, luma.shape[1])
        values = luma[rows, cols] - background[rows // self._bin, cols // self._bin]
        peaks = peak[keep]
        troughs = trough(filtered, peaks, self._trough_px)
        hollows = hollow_depth(
            small,
            k,
            self._history,
            self._fps,
            peaks,
            filtered.ravel()[peaks],
            self._trough_px,
            self._sigma,
        )
        blobs = measure(full_idx, full_labels, values, luma, blob_snr[keep], x, y, troughs, hollows)
        faint_idx, faint_snr = self._faint_cap(faint_idx, faint_snr)
        faint_x, faint_y = subpixel_peak(filtered, faint_idx, self._bin)
        return blobs, FaintPeaks(faint_x, faint_y, faint_snr)

    def _extent_pixels(
        self,
        filtered: NDArray[np.float32],
        noise: PixelNoise,
        background: NDArray[np.float32],
    ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """Flat indices (ascending) and SNR of the pixels above the extent level.

        `noise` holds the tile estimate (at least ``min_noise``) and that times
        ``extent_threshold``; the floor that grows with the background, ``min_noise +
        relative_noise · B``, only raises it, so it is applied to the few pixels above
        the tile level rather than to the frame.
        """
        extent = np.float32(self._params.extent_threshold)
        np.greater(filtered, noise.level, out=self._mask)
        idx = np.flatnonzero(self._mask)  # fast on bool, slow on a uint8 mask
        floor = background.ravel()[idx] * self._params.relative_noise + self._params.min_noise
        sigma = np.maximum(noise.sigma_at(idx).astype(np.float64), floor)
        snr = filtered.ravel()[idx] / sigma
        above = snr > extent
        return idx[above], snr[above]

    def _limit_pixels(
        self, idx: NDArray[np.intp], snr: NDArray[np.float64]
    ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """In a flooded frame, only the `_flood_limit` pixels of highest SNR."""
        limit = self._flood_limit
        if len(idx) <= limit:
            return idx, snr
        self._flooded += 1
        keep = np.sort(np.argpartition(snr, len(snr) - limit)[len(snr) - limit :])
        return idx[keep], snr[keep]

    def _seeded(
        self, idx: NDArray[np.intp], snr: NDArray[np.float64], filtered: NDArray[np.float32]
    ) -> tuple[
        NDArray[np.intp],
        NDArray[np.float64],
        NDArray[np.intp],
        tuple[NDArray[np.intp], NDArray[np.float64]],
        _Crowded,
    ]:
        """Candidate labels of the pixels (-1: no seed), each candidate's SNR and peak,
        the faint peaks (flat index, SNR) and the seeds found beside brighter spots.

        A candidate is a local maximum of the SNR reaching the seed level; a blob
        holding several (two flashes side by side, a flash on a bright rim) is split
        between them, nearest peak first. A blob larger than ``max_area`` (a lamp,
        headlights, and the glow around them) is dropped, however many peaks its plateau
        has, except the seeds that stand out of its light (`_standing_out`): a flash
        seen against a headlight's glow keeps the spot around its peak (`_own_spots`).
        A local maximum from ``lit_threshold`` up to the seed level is a faint peak: it
        neither splits a blob nor becomes a candidate (a maximum is one against every
        pixel around it, so the candidates are the same with or without faint peaks).
        With ``deblend``, a blob of compact spots is also searched for seeds their light
        hides (`pipeline.crowding`); such a seed's SNR is its own light's.
        """
        width = self._binned[1]
        self._pixels.assign(idx)
        blobs = label(self._pixels)
        area = np.bincount(blobs) * self._bin**2 if len(blobs) else np.zeros(0, np.intp)
        too_large = area > self._params.max_area
        self._dropped_by_area += int(np.count_nonzero(too_large))
        in_glow = too_large[blobs]
        threshold = self._threshold
        lowest = min(threshold, self._lit)
        tested = np.where(in_glow, snr >= threshold, snr >= lowest)
        maxima = local_maxima(self._pixels, snr, self._pixels.margin, tested)
        glow_maxima = np.flatnonzero(maxima & in_glow)
        maxima[glow_maxima] = self._standing_out(filtered, idx[glow_maxima], snr[glow_maxima])
        peaks = maxima & (snr >= threshold)
        faint = np.flatnonzero(maxima & (snr < threshold))
        crowded = CrowdedSeeds.empty()
        if self._params.deblend:
            crowded = crowded_seeds(
                self._pixels, idx, snr, filtered, blobs, peaks & ~in_glow, threshold, self._bin
            )
        peaks[crowded.at] = True
        seed_snr = snr.copy()
        seed_snr[crowded.at] = crowded.snr
        labels = split_at_peaks(idx, blobs, peaks, width)
        labels = self._own_spots(idx, labels, in_glow, idx[peaks])
        own = _Crowded(idx[crowded.at], crowded.row, crowded.col)
        return labels, seed_snr[peaks], idx[peaks], (idx[faint], snr[faint]), own

    def _standing_out(
        self, filtered: NDArray[np.float32], idx: NDArray[np.intp], snr: NDArray[np.float64]
    ) -> NDArray[np.bool_]:
        """Which peaks inside an oversized blob stand ``threshold`` σ above the brightest
        filtered response on a ring around them (`ring_max`, at 3 filter σ).

        A flash on a headlight's glow rises above the glow a few pixels uphill; a point
        on a plateau, or at its rim, stands no higher than the plateau next to it.
        """
        if len(idx) == 0:
            return np.zeros(0, bool)
        centre = filtered.ravel()[idx].astype(np.float64)
        ring = ring_max(filtered, idx, self._ring_px)
        return np.asarray(snr * (1.0 - ring / centre) >= self._threshold)

    def _own_spots(
        self,
        idx: NDArray[np.intp],
        labels: NDArray[np.intp],
        in_glow: NDArray[np.bool_],
        peak_idx: NDArray[np.intp],
    ) -> NDArray[np.intp]:
        """`labels` with the pixels of oversized blobs kept only within the local-maximum
        radius of their own peak: the rest is the glow, not the flash."""
        rows = np.flatnonzero(in_glow & (labels >= 0))
        if len(rows) == 0:
            return labels
        width = self._binned[1]
        r, c = np.divmod(idx[rows], width)
        pr, pc = np.divmod(peak_idx[labels[rows]], width)
        dc = np.abs(c - pc)
        distance = np.maximum(np.abs(r - pr), np.minimum(dc, width - dc))
        out = labels.copy()
        out[rows[distance > self._pixels.margin]] = -1
        return out

    def _faint_cap(
        self, idx: NDArray[np.intp], snr: NDArray[np.float64]
    ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """At most ``max_faint_peaks_per_frame`` faint peaks, the highest SNR first,
        in raster order."""
        cap = self._params.max_faint_peaks_per_frame
        if len(idx) <= cap:
            return idx, snr
        self._faint_over_cap += len(idx) - cap
        kept = np.sort(np.argsort(-snr, kind="stable")[:cap])
        return idx[kept], snr[kept]

    def _filter(self, area: NDArray[np.intp], snr: NDArray[np.float64]) -> NDArray[np.intp]:
        """Labels of the candidates within the area bounds, at most the per-frame cap of
        them (the highest SNR first), ascending."""
        area_ok = (area >= self._params.min_area) & (area <= self._params.max_area)
        self._dropped_by_area += int(np.count_nonzero(~area_ok))
        kept = np.flatnonzero(area_ok)
        cap = self._params.max_candidates_per_frame
        if len(kept) > cap:
            self._dropped_over_cap += len(kept) - cap
            kept = np.sort(kept[np.argsort(-snr[kept], kind="stable")[:cap]])
        return kept


@dataclass(frozen=True)
class _Crowded:
    """Seeds beside brighter spots: flat indices (ascending) and sub-pixel centres."""

    idx: NDArray[np.intp]
    row: NDArray[np.float64]
    col: NDArray[np.float64]


def _blur(y: NDArray[np.uint8], sigma: float) -> NDArray[np.uint8]:
    """Gaussian blur that wraps around the 360° seam and replicates the pole rows."""
    pad = math.ceil(3 * sigma)
    wrapped = cv2.copyMakeBorder(y, 0, 0, pad, pad, cv2.BORDER_WRAP)
    blurred = cv2.GaussianBlur(wrapped, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
    return np.asarray(blurred[:, pad:-pad], dtype=np.uint8)


# -- accumulation across frames --------------------------------------------------------


@dataclass(frozen=True)
class FaintPeaks:
    """Local maxima of one frame between ``lit_threshold`` and ``threshold`` σ.

    Attributes
    ----------
    x, y : float64
        Sub-pixel peak of the matched filter's response, pixels (`subpixel_peak`).
    snr : float64
        That response in units of the noise σ.
    """

    x: NDArray[np.float64]
    y: NDArray[np.float64]
    snr: NDArray[np.float64]

    @classmethod
    def empty(cls) -> FaintPeaks:
        return cls(np.zeros(0), np.zeros(0), np.zeros(0))


def _candidate_rows(frame_index: int, blobs: Blobs, recurrence: NDArray[np.float32]) -> Detections:
    return Detections.from_columns(
        np.full(len(blobs), frame_index),
        blobs.x,
        blobs.y,
        area=blobs.area,
        peak=blobs.peak,
        peak_x=blobs.peak_x,
        peak_y=blobs.peak_y,
        snr=blobs.snr,
        recurrence=recurrence,
        trough=blobs.trough,
        hollow=blobs.hollow,
    )


def _faint_rows(frame_index: int, faint: FaintPeaks) -> Detections:
    """Faint peaks as detection rows: frame, position and SNR; the rest neutral."""
    return Detections.from_columns(
        np.full(len(faint.x), frame_index), faint.x, faint.y, snr=faint.snr
    )


class _RowCollector:
    """Per-frame rows gathered into one table; compacted as it grows."""

    _COMPACT_EVERY = 256

    def __init__(self) -> None:
        self._parts: list[Detections] = []
        self._recent: list[Detections] = []

    def add(self, rows: Detections) -> None:
        if len(rows) == 0:
            return
        self._recent.append(rows)
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

    def add(self, frame: Frame, blobs: Blobs) -> None:
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
