"""Flash patterns: flash durations, inter-flash intervals, trains, the night's period, synchrony.

What firefly biologists read from a night (Sarfati et al. 2020, 2021), computed from the
linked 3D flashes of ``trajectories.csv``:

* **A flash** is a streak: a run of consecutive frames in which one firefly is lit
  (`pipeline.trajectories`). Streaks of one trajectory separated by at most
  ``join_gap_frames`` dark frames are one flash whose middle frame the detector missed
  (no firefly's dark phase lasts a single frame). Flash **duration** = number of frames
  from its first to its last lit frame, over fps, in seconds. Flashes cut by the start or
  end of the recording are left out of the duration statistics (their length is unknown).
* **Inter-flash interval** (IFI) = onset to onset of consecutive flashes of one
  trajectory, seconds. An interval longer than ``train_gap_s`` separates two **trains**
  (bursts) and is not an IFI.
* **Per trajectory**: first/last time, number of flashes, median and interquartile range
  of duration, median IFI, number of trains, path length (metres, through its flashes in
  time order), mean speed = path length / time span, and mean height above the ground
  (z + camera height; camera 1 stands level, z up) when the camera height is known.
* **The night**: median and quartiles of durations and IFIs over all flashes; the IFI
  histogram's peak (one-frame bins) as the dominant period; and from the count series
  N(k) (flashes lit in camera-1 frame k) its autocorrelation ρ(τ), whose highest peak in
  ``period_range_s`` is the count series' period.
* **Synchrony**: independent fireflies flashing with their own rhythm make N(k) periodic
  too (each one's autocorrelation adds up), so a peak in ρ alone is no evidence. We
  compare ρ with its distribution over surrogate nights in which every trajectory is
  shifted by a random time (uniform in ±``surrogate_shift_s``, circularly): each
  trajectory keeps its own rhythm, the activity through the night barely changes, only
  the phase relations *between* fireflies are destroyed. The excess e(τ) = (C(τ) − mean
  of the surrogates' C(τ)) / C(0), with C the autocovariance of N, is the part of the
  periodicity that needs fireflies to flash together (each trajectory's own terms cancel
  exactly); its fundamental peak in ``period_range_s`` gives the synchrony period, its
  height the strength (0 for independent flashers, up to ~1), and its z-score against
  the surrogates' spread the significance. A night is synchronous when both pass the
  parameters' thresholds. A periodic series peaks at every multiple of its period, so
  the fundamental is the shortest-lag peak at least half as high as the highest.

All computations are vectorised over points and flashes (group statistics by sorting);
loops run only over the few surrogates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pipeline.params import PatternParams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class Flashes:
    """One row per flash, sorted by trajectory then onset.

    Attributes
    ----------
    trajectory_id : ndarray of int64
    first_frame, last_frame : ndarray of int64
        First and last lit camera-1 frame (inclusive).
    censored : ndarray of bool
        Touches the first or last frame of the recording: its duration is unknown.
    """

    trajectory_id: IntArray
    first_frame: IntArray
    last_frame: IntArray
    censored: NDArray[np.bool_]

    def __len__(self) -> int:
        return len(self.first_frame)

    @property
    def n_frames(self) -> IntArray:
        """Lit frames from first to last (inclusive)."""
        return self.last_frame - self.first_frame + 1


def flashes_from_streaks(
    trajectory_id: IntArray,
    streak_id: IntArray,
    frame: IntArray,
    join_gap_frames: int = 1,
    n_frames: int | None = None,
) -> Flashes:
    """Flashes from the rows of a trajectories table (one row per lit point).

    Parameters
    ----------
    trajectory_id, streak_id, frame : ndarray of int
        Per point (``trajectories.csv`` columns).
    join_gap_frames : int
        Streaks of one trajectory with at most this many dark frames between them are
        one flash.
    n_frames : int, optional
        Length of the recording in frames: flashes touching frame 0 or the last frame
        are marked censored.
    """
    trajectory_id, streak_id, frame = (
        np.asarray(a, dtype=np.int64) for a in (trajectory_id, streak_id, frame)
    )
    if len(frame) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return Flashes(empty, empty, empty, np.zeros(0, dtype=bool))
    streaks, inverse = np.unique(streak_id, return_inverse=True)
    first = np.full(len(streaks), np.iinfo(np.int64).max)
    last = np.full(len(streaks), np.iinfo(np.int64).min)
    np.minimum.at(first, inverse, frame)
    np.maximum.at(last, inverse, frame)
    owner = np.zeros(len(streaks), dtype=np.int64)
    owner[inverse] = trajectory_id
    order = np.lexsort((first, owner))
    owner, first, last = owner[order], first[order], last[order]
    # A streak continues the previous flash when it is of the same trajectory and starts
    # within join_gap_frames dark frames of its end.
    joins = np.zeros(len(first), dtype=bool)
    joins[1:] = (owner[1:] == owner[:-1]) & (first[1:] - last[:-1] - 1 <= join_gap_frames)
    flash = np.cumsum(~joins) - 1
    n = int(flash[-1]) + 1
    f_first = np.full(n, np.iinfo(np.int64).max)
    f_last = np.full(n, np.iinfo(np.int64).min)
    np.minimum.at(f_first, flash, first)
    np.maximum.at(f_last, flash, last)
    f_owner = owner[~joins]
    censored = f_first <= 0
    if n_frames is not None:
        censored |= f_last >= n_frames - 1
    return Flashes(f_owner, f_first, f_last, censored)


def intervals(flashes: Flashes, fps: float, train_gap_s: float) -> tuple[FloatArray, IntArray]:
    """Onset-to-onset intervals within trains, and each flash's train number.

    Returns
    -------
    ifi_s : ndarray
        Intervals (seconds) between consecutive flashes of a trajectory that are at most
        ``train_gap_s`` apart.
    train : ndarray of int64
        Per flash, a night-wide train index (consecutive within a trajectory).
    """
    gap_s = np.diff(flashes.first_frame) / fps
    within = within_trains(flashes, fps, train_gap_s)
    if len(flashes) == 0:
        return gap_s, np.zeros(0, dtype=np.int64)
    train = np.concatenate([[0], np.cumsum(~within)]).astype(np.int64)
    return gap_s[within], train


def within_trains(flashes: Flashes, fps: float, train_gap_s: float) -> NDArray[np.bool_]:
    """Per pair of consecutive flashes: same trajectory, onsets at most `train_gap_s` apart."""
    same = flashes.trajectory_id[1:] == flashes.trajectory_id[:-1]
    return same & (np.diff(flashes.first_frame) / fps <= train_gap_s)


def group_quantiles(
    groups: IntArray, values: FloatArray, quantiles: tuple[float, ...]
) -> tuple[IntArray, FloatArray]:
    """Quantiles (linear interpolation, as `numpy.quantile`) of `values` per group.

    Returns the sorted unique groups and an array ``(n_groups, len(quantiles))``; NaN
    values are ignored (a group with none left gets NaN).
    """
    keep = np.isfinite(values)
    unique = np.unique(groups)
    out = np.full((len(unique), len(quantiles)), np.nan)
    if not keep.any():
        return unique, out
    g, v = groups[keep], values[keep]
    order = np.lexsort((v, g))
    g, v = g[order], v[order]
    present, starts, counts = np.unique(g, return_index=True, return_counts=True)
    rows = np.searchsorted(unique, present)
    for j, q in enumerate(quantiles):
        position = starts + q * (counts - 1)
        low = np.floor(position).astype(np.int64)
        high = np.minimum(low + 1, starts + counts - 1)
        out[rows, j] = v[low] + (position - low) * (v[high] - v[low])
    return unique, out


def _distribution(values: FloatArray) -> dict[str, Any]:
    """Median, quartiles and count of a sample (None when empty)."""
    if len(values) == 0:
        return {"median": None, "q25": None, "q75": None, "n": 0}
    q25, median, q75 = np.quantile(values, [0.25, 0.5, 0.75])
    return {"median": float(median), "q25": float(q25), "q75": float(q75), "n": len(values)}


def histogram_mode(values_s: FloatArray, fps: float) -> float | None:
    """Peak of the histogram of durations in one-frame bins (smoothed 1-2-1), seconds.

    The peak bin is refined to the mean of the values within a bin of it.
    """
    if len(values_s) == 0:
        return None
    bins = np.round(values_s * fps).astype(np.int64)
    counts = np.bincount(bins).astype(np.float64)
    smooth = np.convolve(counts, [0.25, 0.5, 0.25], mode="same")
    peak = int(np.argmax(smooth))
    near = np.abs(bins - peak) <= 1
    return float(values_s[near].mean())


def per_trajectory(
    table: dict[str, np.ndarray],
    flashes: Flashes,
    fps: float,
    params: PatternParams,
    camera_height_m: float | None,
) -> dict[str, np.ndarray]:
    """The columns of ``flash_patterns.csv`` (before the clock's), one row per trajectory.

    `table` holds the ``trajectories.csv`` columns (x, y, z, frame, trajectory_id…).
    """
    tid = np.asarray(table["trajectory_id"], dtype=np.int64)
    frame = np.asarray(table["frame"], dtype=np.int64)
    xyz = np.column_stack([table["x"], table["y"], table["z"]]).astype(np.float64)
    ids, inverse = np.unique(tid, return_inverse=True)
    n = len(ids)
    first = np.full(n, np.iinfo(np.int64).max)
    last = np.full(n, np.iinfo(np.int64).min)
    np.minimum.at(first, inverse, frame)
    np.maximum.at(last, inverse, frame)
    points = np.bincount(inverse, minlength=n)

    # Path through the points in time order: consecutive rows of one trajectory.
    order = np.lexsort((frame, tid))
    step = np.linalg.norm(np.diff(xyz[order], axis=0), axis=1)
    same = tid[order][1:] == tid[order][:-1]
    path = np.bincount(inverse[order][1:][same], weights=step[same], minlength=n)
    span_s = (last - first) / fps
    with np.errstate(invalid="ignore", divide="ignore"):
        speed = np.where(span_s > 0, path / span_s, np.nan)
    if camera_height_m is None:
        height = np.full(n, np.nan)
    else:
        height = np.bincount(inverse, weights=xyz[:, 2], minlength=n) / points + camera_height_m

    duration_s = np.where(flashes.censored, np.nan, flashes.n_frames / fps)
    _, dq = group_quantiles(flashes.trajectory_id, duration_s, (0.25, 0.5, 0.75))
    dq = _align(ids, np.unique(flashes.trajectory_id), dq)
    ifi_s, train = intervals(flashes, fps, params.train_gap_s)
    ifi_owner = flashes.trajectory_id[1:][within_trains(flashes, fps, params.train_gap_s)]
    ifi_ids, iq = group_quantiles(ifi_owner, ifi_s, (0.5,))
    ifi_median = _align(ids, ifi_ids, iq)[:, 0]
    n_flashes = np.bincount(np.searchsorted(ids, flashes.trajectory_id), minlength=n)
    trains_of = np.unique(np.column_stack([flashes.trajectory_id, train]), axis=0)[:, 0]
    n_trains = np.bincount(np.searchsorted(ids, trains_of), minlength=n)
    return {
        "trajectory_id": ids,
        "first_frame": first,
        "last_frame": last,
        "first_time_s": first / fps,
        "last_time_s": last / fps,
        "n_points": points,
        "n_flashes": n_flashes,
        "flash_duration_median_s": dq[:, 1],
        "flash_duration_iqr_s": dq[:, 2] - dq[:, 0],
        "ifi_median_s": ifi_median,
        "n_trains": n_trains,
        "path_length_m": path,
        "mean_speed_mps": speed,
        "mean_height_m": height,
    }


def _align(ids: IntArray, present: IntArray, values: FloatArray) -> FloatArray:
    """Rows of `values` (for the groups `present`) placed at their `ids`; NaN elsewhere."""
    out = np.full((len(ids), values.shape[1]), np.nan)
    out[np.searchsorted(ids, present)] = values
    return out


def autocovariance(series: FloatArray, max_lag: int) -> FloatArray:
    """Circular autocovariance of a series (mean removed) at lags 0..max_lag."""
    centred = series - series.mean()
    spectrum = np.fft.rfft(centred)
    return np.fft.irfft(spectrum * np.conj(spectrum), n=len(series))[: max_lag + 1]


def autocorrelation(series: FloatArray, max_lag: int) -> FloatArray:
    """Circular autocorrelation of a series (mean removed, ρ(0) = 1) at lags 0..max_lag."""
    acf = autocovariance(series, max_lag)
    return acf / acf[0] if acf[0] > 0 else np.zeros(max_lag + 1)


#: A peak at least this fraction of the highest one, at a shorter lag, is the fundamental
#: period (the highest can be a multiple of it: a periodic series peaks at every multiple).
HARMONIC_FRACTION = 0.5


def _peak(curve: FloatArray, lo: int, hi: int) -> int | None:
    """Lag of the fundamental peak of `curve` within [lo, hi], or None.

    Among the local maxima, the shortest lag whose height is at least
    `HARMONIC_FRACTION` of the highest (and positive).
    """
    lags = np.arange(max(lo, 1), min(hi, len(curve) - 2) + 1)
    if len(lags) == 0:
        return None
    local = (curve[lags] >= curve[lags - 1]) & (curve[lags] >= curve[lags + 1])
    if not local.any():
        return None
    candidates = lags[local]
    best = curve[candidates].max()
    if best <= 0:
        return int(candidates[np.argmax(curve[candidates])])
    return int(candidates[curve[candidates] >= HARMONIC_FRACTION * best][0])


def count_series(frame: IntArray, n_frames: int) -> FloatArray:
    """N(k): flashes lit in each camera-1 frame ``k`` of ``[0, n_frames)``."""
    counts = np.bincount(np.asarray(frame, dtype=np.int64), minlength=n_frames)
    return counts[:n_frames].astype(np.float64)


def synchrony(
    frame: IntArray, trajectory_id: IntArray, n_frames: int, fps: float, params: PatternParams
) -> dict[str, Any]:
    """Period of the count series and the synchrony test against shifted surrogates.

    Returns
    -------
    dict
        ``count_period_s`` and ``count_autocorrelation`` (the highest autocorrelation
        peak of N(k) in the period range), ``synchronous`` (bool, None when there are
        fewer than ``min_trajectories`` trajectories), ``period_s``, ``strength`` and
        ``z`` of the surrogate-corrected peak.
    """
    frame = np.asarray(frame, dtype=np.int64)
    tid = np.asarray(trajectory_id, dtype=np.int64)
    lo = max(int(np.floor(params.period_range_s[0] * fps)), 1)
    hi = int(np.ceil(params.period_range_s[1] * fps))
    result: dict[str, Any] = {
        "count_period_s": None,
        "count_autocorrelation": None,
        "synchronous": None,
        "period_s": None,
        "strength": None,
        "z": None,
    }
    if len(frame) == 0 or n_frames < 2 * hi + 2:
        return result
    acov = autocovariance(count_series(frame, n_frames), hi + 1)
    if acov[0] <= 0:
        return result
    rho = acov / acov[0]
    lag = _peak(rho, lo, hi)
    if lag is not None:
        result["count_period_s"] = lag / fps
        result["count_autocorrelation"] = float(rho[lag])
    ids, inverse = np.unique(tid, return_inverse=True)
    if len(ids) < params.min_trajectories:
        return result
    rng = np.random.default_rng(params.seed)
    shift = max(round(params.surrogate_shift_s * fps), 1)
    surrogates = np.empty((params.n_surrogates, hi + 2))
    for s in range(params.n_surrogates):
        offsets = rng.integers(-shift, shift + 1, len(ids))
        shifted = (frame + offsets[inverse]) % n_frames
        surrogates[s] = autocovariance(count_series(shifted, n_frames), hi + 1)
    # Autocovariances, not correlations: a shift keeps each trajectory's own terms and the
    # mean exactly, so the difference is the between-firefly part alone, at every lag (the
    # variances differ: flashes piling up in a synchronous night raise the original's).
    mean, spread = surrogates.mean(axis=0) / acov[0], surrogates.std(axis=0, ddof=1) / acov[0]
    excess = rho - mean
    peak = _peak(excess, lo, hi)
    if peak is None:
        result["synchronous"] = False
        return result
    strength = float(excess[peak])
    z = float(strength / spread[peak]) if spread[peak] > 0 else float("inf")
    result.update(
        period_s=peak / fps,
        strength=strength,
        z=z,
        synchronous=bool(strength >= params.min_sync_strength and z >= params.min_sync_z),
    )
    return result


def night_patterns(
    table: dict[str, np.ndarray], fps: float, n_frames: int, params: PatternParams
) -> tuple[Flashes, dict[str, Any]]:
    """The night's flashes and its figures (durations, IFIs, period, synchrony).

    Returns
    -------
    flashes : Flashes
    figures : dict
        ``n_flashes``, ``n_trajectories``, ``n_trains``, ``flash_duration_s`` and
        ``ifi_s`` (``median``, ``q25``, ``q75``, ``n``; ``ifi_s`` also ``mode``: the
        histogram peak), ``flashes_per_train`` (median), and the `synchrony` figures.
    """
    tid = np.asarray(table["trajectory_id"], dtype=np.int64)
    frame = np.asarray(table["frame"], dtype=np.int64)
    flashes = flashes_from_streaks(tid, table["streak_id"], frame, params.join_gap_frames, n_frames)
    durations = flashes.n_frames[~flashes.censored] / fps
    ifi_s, train = intervals(flashes, fps, params.train_gap_s)
    per_train = np.bincount(train) if len(train) else np.zeros(0, dtype=np.int64)
    figures: dict[str, Any] = {
        "n_flashes": len(flashes),
        "n_trajectories": len(np.unique(tid)),
        "n_trains": len(per_train),
        "flash_duration_s": _distribution(durations),
        "ifi_s": {**_distribution(ifi_s), "mode": histogram_mode(ifi_s, fps)},
        "flashes_per_train": float(np.median(per_train)) if len(per_train) else None,
        **synchrony(frame, tid, n_frames, fps, params),
    }
    return flashes, figures
