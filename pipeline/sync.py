"""Temporal calibration: the frame delay between the two cameras.

The per-frame flash counts ``N1(k)`` and ``N2(k)`` of the two cameras are the same
signal shifted in time (both see most of the same flashes). The delay is the lag of
their cross-correlation, made robust as in Sarfati's oorb:

1. frames whose count is an outlier (transient light pollution makes counts explode)
   are neutralised, and so are the key frames (both cameras' encoders code a frame
   whole at the same indices, every second or so, and on a grainy night each such
   frame bursts with speckle confident enough to count: in step with each other, at
   lags of whole key intervals, whatever the true delay); leading / trailing empty
   stretches are trimmed;
2. RANSAC: many random windows of camera 1 are each matched against camera 2 over the
   whole lag range by zero-normalised cross-correlation (one batched FFT), each window
   votes for its best lag;
3. the delay is the modal vote and the confidence the fraction of windows that agree.

Delay convention (CONTRACT): ``delay_frames`` ``dk`` means camera-1 frame ``k`` shows
the same instant as camera-2 frame ``k + dk``; ``dk`` may be negative.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray
from scipy import fft, signal

from pipeline.params import SyncParams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: ``1.4826 × MAD`` estimates the standard deviation of Gaussian data.
_MAD_TO_SIGMA = 1.4826
#: RANSAC windows correlated per FFT batch.
_WINDOW_BATCH = 50
#: Key frames are neutralised only while they are at most this share of a camera's
#: frames: an intra-only recording (every frame a key frame) renews its grain evenly.
MAX_KEY_FRAME_SHARE = 0.25
#: Share of camera 1's active stretch a shortened RANSAC window covers (`_window_length`):
#: long enough to hold most of its flashes, short enough that random windows differ.
SHORT_WINDOW_SHARE = 2 / 3


class SyncError(ValueError):
    """The delay cannot be estimated at all (no flashes, recordings too short, ...)."""


@dataclass(frozen=True)
class DelayEstimate:
    """Result of `estimate_delay`.

    Attributes
    ----------
    delay_frames : int
        ``dk``: camera-1 frame ``k`` shows the same instant as camera-2 frame ``k + dk``.
    confidence : float
        Fraction (0–1) of the voting windows whose vote agrees with ``delay_frames``.
    n_windows : int
        Number of windows that voted (windows without any flash contrast do not).
    votes : ndarray of int64
        The delay, in frames, voted by each window.
    lags : ndarray of int64
        Delays (frames) of the global correlation curve, ``-max .. +max``.
    correlation : ndarray of float64
        Global normalised cross-correlation of the cleaned count series at ``lags``
        (1 would be a perfect match), for the report plot.
    warnings : tuple of str
        Reasons to distrust the estimate (low confidence, delay at the search bound).
    set_aside : (int, int)
        Frames of camera 1 and camera 2 neutralised before correlating (light-pollution
        outliers and key frames, `clean_counts`).
    """

    delay_frames: int
    confidence: float
    n_windows: int
    votes: IntArray
    lags: IntArray
    correlation: FloatArray
    warnings: tuple[str, ...] = field(default=())
    set_aside: tuple[int, int] = (0, 0)

    def to_dict(self, include_curve: bool = True) -> dict[str, Any]:
        """JSON-ready summary; ``include_curve=False`` leaves out the (long) curve."""
        out: dict[str, Any] = {
            "delay_frames": self.delay_frames,
            "confidence": self.confidence,
            "n_windows": self.n_windows,
            "votes": self.votes.tolist(),
            "warnings": list(self.warnings),
            "frames_set_aside": list(self.set_aside),
        }
        if include_curve:
            out["lags"] = self.lags.tolist()
            out["correlation"] = self.correlation.tolist()
        return out


def estimate_delay(
    counts1: ArrayLike,
    counts2: ArrayLike,
    fps: float,
    params: SyncParams = SyncParams(),  # noqa: B008 - frozen, immutable default
    key_frames: tuple[ArrayLike | None, ArrayLike | None] = (None, None),
) -> DelayEstimate:
    """Frame delay between two cameras from their per-frame flash counts.

    Parameters
    ----------
    counts1, counts2 : array_like of int, shape (n1,), (n2,)
        Flash counts ``N1(k)``, ``N2(k)`` per frame (`Detections.counts_per_frame`);
        the recordings may have different lengths.
    fps : float
        Frame rate of both cameras, in frames per second (converts the ``*_s``
        parameters to frames).
    params : SyncParams
        Lag bound, RANSAC window length and count, agreement tolerance, seed.
    key_frames : (array_like of int or None, array_like of int or None)
        Each camera's key frames (`pipeline.video.Frame.key`), neutralised like outlier
        frames where they are rare (`MAX_KEY_FRAME_SHARE`); None where unknown.

    Returns
    -------
    DelayEstimate
        ``delay_frames`` ``dk`` with camera-1 frame ``k`` ≡ camera-2 frame ``k + dk``.
        A low confidence is reported in ``warnings``, not raised.

    Raises
    ------
    SyncError
        If a camera has no flashes, or camera 1's active stretch is too short for a
        window of ``min_window_s`` (a stretch shorter than ``window_s`` shortens the
        windows, with a warning).
    ValueError
        If the counts are not 1-D finite non-negative series or ``fps`` is not positive.
    """
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    clean1, clean2 = (
        clean_counts(series, params.outlier_mads, f"camera {i}", _rare(keys, len(series)))
        for i, series, keys in (
            (1, _as_counts(counts1, "counts1"), key_frames[0]),
            (2, _as_counts(counts2, "counts2"), key_frames[1]),
        )
    )
    max_lag = max(1, round(params.max_delay_s * fps))
    window, warnings = _window_length(clean1.last - clean1.first, fps, params)
    x1, x2 = clean1.centred(), clean2.centred()
    lags, correlation = global_correlation(x1, x2, max_lag)
    starts = _window_starts(clean1, window, params)
    # Batches bound the memory: each window holds (window + 2 max_lag) FFT samples.
    votes = np.concatenate(
        [
            window_votes(x1, x2, starts[i : i + _WINDOW_BATCH], window, max_lag)
            for i in range(0, len(starts), _WINDOW_BATCH)
        ]
    )
    if len(votes) == 0:
        raise SyncError("no RANSAC window of camera 1 contains any flash contrast")
    delay = _modal_vote(votes, lags, correlation)
    confidence = float(np.mean(np.abs(votes - delay) <= params.agree_frames))
    if confidence < params.min_confidence:
        warnings.append(
            f"low delay confidence {confidence:.2f} ({len(votes)} windows, delay {delay} frames)"
        )
    if abs(delay) >= max_lag:
        warnings.append(
            f"delay {delay} frames is at the search bound ±{max_lag} (max_delay_s="
            f"{params.max_delay_s}): the true delay may lie beyond it"
        )
    return DelayEstimate(
        delay_frames=delay,
        confidence=confidence,
        n_windows=len(votes),
        votes=votes,
        lags=lags,
        correlation=correlation,
        warnings=tuple(warnings),
        set_aside=(clean1.set_aside, clean2.set_aside),
    )


class CleanCounts(NamedTuple):
    """A count series prepared for correlation (see `clean_counts`)."""

    #: Counts as float, outlier frames set to the mean of the clean active frames.
    series: FloatArray
    #: First frame with a clean flash.
    first: int
    #: One past the last frame with a clean flash.
    last: int
    #: Frames with a clean (non-outlier) non-zero count.
    flash_frames: IntArray
    #: Frames neutralised (outliers and skipped frames).
    set_aside: int

    def centred(self) -> FloatArray:
        """Series minus its active-stretch mean, zero outside ``[first, last)``.

        Zero is then neutral: trimmed stretches and outlier frames add nothing to a
        correlation.
        """
        out = np.zeros_like(self.series)
        active = self.series[self.first : self.last]
        out[self.first : self.last] = active - active.mean()
        return out


def clean_counts(
    counts: IntArray, outlier_mads: float, name: str = "camera", skip: ArrayLike | None = None
) -> CleanCounts:
    """Neutralise outlier frames (and the frames to `skip`) and trim the empty ends of a
    count series.

    Parameters
    ----------
    counts : ndarray of int64
        Flashes per frame.
    outlier_mads : float
        Counts above ``median + outlier_mads · max(1.4826 MAD, 1)`` of the non-zero
        counts are outliers (light pollution makes counts explode).
    name : str
        Camera name for error messages.
    skip : array_like of int, optional
        Frames neutralised like outliers whatever their count (key frames); indices
        outside the series are ignored.

    Returns
    -------
    CleanCounts
        Outlier and skipped frames are replaced by the mean count of the clean frames of
        the active stretch ``[first, last)`` (leading and trailing empty stretches
        trimmed), so that they add nothing to a mean-subtracted correlation.

    Raises
    ------
    SyncError
        If no frame has a clean non-zero count.
    """
    nonzero = counts[counts > 0]
    if len(nonzero) == 0:
        raise SyncError(f"{name} has no flashes: its delay cannot be estimated")
    median = np.median(nonzero)
    sigma = max(_MAD_TO_SIGMA * float(np.median(np.abs(nonzero - median))), 1.0)
    outlier = counts > median + outlier_mads * sigma
    if skip is not None:
        skipped = np.asarray(skip, dtype=np.int64)
        outlier[skipped[(skipped >= 0) & (skipped < len(counts))]] = True
    flash_frames = np.flatnonzero((counts > 0) & ~outlier)
    if len(flash_frames) == 0:
        raise SyncError(f"{name} has only outlier frames (light pollution?), no usable flashes")
    first, last = int(flash_frames[0]), int(flash_frames[-1]) + 1
    clean_active = counts[first:last][~outlier[first:last]]
    series = np.where(outlier, clean_active.mean(), counts.astype(np.float64))
    return CleanCounts(
        series, first, last, flash_frames.astype(np.int64), int(np.count_nonzero(outlier))
    )


def global_correlation(y1: FloatArray, y2: FloatArray, max_lag: int) -> tuple[IntArray, FloatArray]:
    """Normalised cross-correlation ``Σ_k y1(k) y2(k + dk) / sqrt(Σ y1² Σ y2²)``.

    Parameters
    ----------
    y1, y2 : ndarray of float64
        Centred count series (`CleanCounts.centred`) of camera 1 and camera 2.
    max_lag : int
        Largest ``|dk|`` kept, in frames.

    Returns
    -------
    lags : ndarray of int64
        Delays ``dk`` in frames (those within ``±max_lag`` that overlap at all).
    correlation : ndarray of float64
        Correlation at each lag, computed by FFT.
    """
    full = signal.correlate(y2, y1, mode="full", method="fft")
    all_lags = signal.correlation_lags(len(y2), len(y1), mode="full")
    keep = np.abs(all_lags) <= max_lag
    norm = np.sqrt(np.sum(y1**2) * np.sum(y2**2))
    return all_lags[keep].astype(np.int64), full[keep] / (norm if norm > 0 else 1.0)


def window_votes(
    x1: FloatArray, x2: FloatArray, starts: IntArray, window: int, max_lag: int
) -> IntArray:
    """Best delay of each camera-1 window by zero-normalised cross-correlation.

    Parameters
    ----------
    x1, x2 : ndarray of float64
        Centred count series (`CleanCounts.centred`) of camera 1 and camera 2.
    starts : ndarray of int64
        First camera-1 frame of each window.
    window : int
        Window length in frames.
    max_lag : int
        Largest ``|dk|`` searched, in frames.

    Window ``[s, s + window)`` of ``x1`` is compared with ``x2[s + dk : s + dk + window]``
    for every ``dk`` in ``[-max_lag, max_lag]`` (camera 2 is zero beyond its ends) where
    camera 2 recorded at least half of that stretch: a stretch mostly past its ends holds
    a flash or two, whose normalised correlation with any window is spuriously high (a
    15 s, 60 fps wind night voted 861 frames, 39 frames of overlap, over the true -40).
    All windows are correlated in one batched FFT. Windows without contrast (constant
    counts) do not vote.

    Returns
    -------
    ndarray of int64
        One delay (frames) per voting window.
    """
    n_lags = 2 * max_lag + 1
    padded = np.zeros(max_lag + max(len(x1), len(x2)) + max_lag + window)
    padded[max_lag : max_lag + len(x2)] = x2
    # segments[i, j] is camera-2 frame starts[i] - max_lag + j.
    segments = sliding_window_view(padded, window + n_lags - 1)[starts]
    templates = sliding_window_view(x1, window)[starts]
    templates = templates - templates.mean(axis=1, keepdims=True)
    n_fft = fft.next_fast_len(window + n_lags - 1, real=True)
    numerator = fft.irfft(
        fft.rfft(segments, n_fft, axis=1) * np.conj(fft.rfft(templates, n_fft, axis=1)),
        n_fft,
        axis=1,
    )[:, :n_lags]
    # Local energy of camera 2 under the window at each lag, from cumulative sums.
    csum = np.concatenate([[0.0], np.cumsum(padded)])
    csum2 = np.concatenate([[0.0], np.cumsum(padded**2)])
    first = starts[:, None] + np.arange(n_lags)
    s1 = csum[first + window] - csum[first]
    s2 = csum2[first + window] - csum2[first]
    local_var = np.maximum(s2 - s1**2 / window, 0.0)
    template_norm = np.sqrt(np.sum(templates**2, axis=1))
    # A flat camera-2 stretch carries no timing information: score it 0, not 0/0.
    score = np.where(local_var > 1e-9, numerator / np.sqrt(np.maximum(local_var, 1e-9)), 0.0)
    camera2 = first - max_lag  # camera-2 frame of each stretch's start
    recorded = np.minimum(camera2 + window, len(x2)) - np.maximum(camera2, 0)
    score = np.where(2 * recorded >= window, score, -np.inf)
    votes = np.argmax(score, axis=1) - max_lag
    voting = (template_norm > 0) & np.isfinite(score.max(axis=1))
    return votes[voting].astype(np.int64)


def _as_counts(counts: ArrayLike, name: str) -> IntArray:
    arr = np.asarray(counts)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D per-frame count series, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{name} must hold finite non-negative counts")
    return arr.astype(np.int64)


def _rare(key_frames: ArrayLike | None, n_frames: int) -> ArrayLike | None:
    """`key_frames` if they are at most `MAX_KEY_FRAME_SHARE` of `n_frames`, else None."""
    if key_frames is None or len(np.asarray(key_frames)) > MAX_KEY_FRAME_SHARE * n_frames:
        return None
    return key_frames


def _window_length(active1: int, fps: float, params: SyncParams) -> tuple[int, list[str]]:
    """RANSAC window in frames, shortened when camera 1's flashes span less than one.

    A shortened window covers `SHORT_WINDOW_SHARE` of the active stretch, so the random
    windows still differ from one another; below ``min_window_s`` too few flashes fall
    in a window to tell one lag from another.

    Returns
    -------
    window : int
        Window length, in frames.
    warnings : list of str
        Why the window was shortened (the estimate is then less certain), or nothing.

    Raises
    ------
    SyncError
        If the shortened window would be shorter than ``min_window_s``.
    """
    window = max(2, round(params.window_s * fps))
    if active1 >= window:
        return window, []
    shortened = math.floor(SHORT_WINDOW_SHARE * active1)
    if shortened < params.min_window_s * fps:
        raise SyncError(
            f"camera 1 has flashes over only {active1} frames ({active1 / fps:.1f} s): too "
            f"short to estimate the delay (a window of at least min_window_s="
            f"{params.min_window_s} s must fit {SHORT_WINDOW_SHARE:.2f} of that stretch)"
        )
    return shortened, [
        f"camera 1 has flashes over only {active1 / fps:.1f} s, shorter than one "
        f"window_s={params.window_s} s window: windows shortened to {shortened / fps:.1f} s, "
        "the delay of a short recording is less certain"
    ]


def _window_starts(clean1: CleanCounts, window: int, params: SyncParams) -> IntArray:
    """Random window starts, each window centred on a random camera-1 flash frame.

    Centring on flashes keeps windows where the data are: sparse activity in a long
    recording would otherwise leave most uniform windows empty.
    """
    rng = np.random.default_rng(params.seed)
    centres = rng.choice(clean1.flash_frames, size=params.n_windows, replace=True)
    return np.clip(centres - window // 2, clean1.first, clean1.last - window).astype(np.int64)


def _modal_vote(votes: IntArray, lags: IntArray, correlation: FloatArray) -> int:
    """Most voted delay; ties go to the higher global correlation, then the smaller |dk|."""
    values, n = np.unique(votes, return_counts=True)
    tied = values[n == n.max()]
    curve = np.full(len(tied), -np.inf)
    found = np.isin(tied, lags)
    curve[found] = correlation[np.searchsorted(lags, tied[found])]
    best = np.lexsort((np.abs(tied), -curve))[0]
    return int(tied[best])
