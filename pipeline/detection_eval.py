"""How well the detector finds flashes: 2D recall and precision per camera, binned by
peak signal-to-noise ratio and by range, candidate rates, and 3D recall and precision.

Scores a run folder (`pipeline.run.process` output) against the simulator's ground
truth (`pipeline.simulate.GroundTruth`), with the matching and tolerances of
`pipeline.evaluate`:

- 2D, per camera: a true flash-frame visible in the camera is *found* when a detection
  of the same frame lies within `evaluate.DETECTION_TOLERANCE_PX` (equatorial pixels);
  a detection is *true* when a visible true flash of its frame lies that close. Scored
  twice: the accepted detections (``flashes_cam*.csv``) and every tracked candidate
  before acceptance (``work/candidates_cam*.npz``).
- 3D: a true flash-frame seen by both cameras is *found* when a triangulated point of
  its camera-1 frame lies within `evaluate.IDENTITY_TOLERANCE` (5 %) of its range
  (also reported at `evaluate.RANGE_TOLERANCE`, 2 %: the project's accuracy target);
  a point is *true* when within 5 % of the range of the nearest true flash of its frame.
  The stereo pairing is scored apart (`pair_figures`): a point is a *true pair* when
  its two detections (``work/points.npz`` ``index1``/``index2``) are of one true
  flash-frame, whatever its range error, and a flash-frame is *found paired* when it
  has such a point; the gap between the two says what is range resolution.

Bins: peak SNR = drawn peak amplitude over the noise σ at the flash's pixel (truth
columns ``snr1``/``snr2``; 3D uses the smaller of the two), the SNR at a matched
filter's peak against the same sensor noise (``snr_mf1``/``snr_mf2``: grain correlated
over a flash's size does not average away under a filter, so a "5 σ" flash of the
per-pixel yardstick can stand under 4 σ for any detector; 2D only) and range from the camera
(``range1``/``range2``; 3D uses camera 1's). The position error of each found
flash-frame (distance to its nearest detection, equatorial pixels) is binned too, and
its median given per run: sub-pixel errors are what put faint, distant flashes outside
5 % of their range at low resolution. Every figure keeps its counts, so runs (seeds)
pool exactly (`pool`; medians are per run only).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from pipeline import artifacts
from pipeline.detections import Detections
from pipeline.evaluate import (
    DETECTION_TOLERANCE_PX,
    IDENTITY_TOLERANCE,
    RANGE_TOLERANCE,
    DetectionMatch,
    PointMatch,
    camera_points,
    match_detections,
    match_points,
)
from pipeline.results import load_points, read_trajectories
from pipeline.simulate import GroundTruth
from pipeline.triangulate import sure_of_range

#: Version of the JSON layout written by ``firefly3d eval-detection --json``.
SCHEMA_VERSION = 1
#: Peak-SNR bin edges (the last bin is open).
SNR_EDGES: tuple[float, ...] = (0.0, 3.0, 5.0, 10.0, 20.0, math.inf)
#: Range bin edges in metres (the last bin is open; the simulator stays within ~21 m).
RANGE_EDGES_M: tuple[float, ...] = (0.0, 5.0, 8.0, 20.0, math.inf)
#: Point-spread σ bin edges (pixels of the recording) for the flash-frames >= 5 σ: the
#: simulator draws 0.6–2 px; the real GoPro 360 flash patches' spots are σ ≈ 1.2–1.9 px
#: (docs/detection.md, "At 4K").
PSF_EDGES_PX: tuple[float, ...] = (0.0, 0.8, 1.2, 1.6, math.inf)
#: Position-error bin edges of found flash-frames, equatorial pixels (the last is the
#: match tolerance).
ERROR_EDGES_PX: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3, 0.5, 1.0, DETECTION_TOLERANCE_PX)
#: The headline 2D figure: recall of flash-frames at or above this peak SNR (target 0.95).
HEADLINE_SNR = 5.0
#: A point's range is covered when within this many of its standard deviations.
COVERAGE_SDS = 2.0
#: A false detection this close (equatorial pixels) to a true flash of its frame is
#: a fragment of it (halo, streak split), not an independent false positive.
NEAR_FLASH_PX = 5.0
#: A missed flash-frame this many frames or fewer from a found frame of the same flash
#: is counted as lost *beside* it (the rise or the fall of a flash that was seen):
#: what a search guided by the found frames could still recover.
BESIDE_FRAMES = 2


# -- bins ---------------------------------------------------------------------------------


def _label(lo: float, hi: float) -> str:
    def fmt(x: float) -> str:
        return f"{x:g}"

    if math.isinf(hi):
        return f">={fmt(lo)}"
    return f"{fmt(lo)}-{fmt(hi)}"


def ratio(numerator: float, denominator: float) -> float | None:
    """``numerator / denominator``, None (JSON null) when the denominator is 0."""
    return float(numerator) / denominator if denominator else None


def binned(
    values: NDArray, hits: Sequence[tuple[str, NDArray[np.bool_]]], edges: Sequence[float]
) -> list[dict[str, Any]]:
    """Count items and hits per bin of ``values``.

    Parameters
    ----------
    values : ndarray
        One value per item; NaN values (unknown, e.g. old truth files) go to a last
        bin labelled ``unknown`` (listed only when it holds items).
    hits : sequence of (name, ndarray of bool)
        Per item flags; each bin gets ``<name>`` (count) and ``<name>_rate``
        (count / n, None when the bin is empty). The first flag also gives ``recall``.
    edges : sequence of float
        Increasing bin edges; bin ``i`` is ``[edges[i], edges[i+1])``.

    Returns
    -------
    list of dict
        ``{"label", "lo", "hi", "n", <name>, <name>_rate, ...}``; ``hi`` is None for
        an open last bin.
    """
    values = np.asarray(values, dtype=np.float64)
    n_bins = len(edges) - 1
    known = ~np.isnan(values)
    inner = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, n_bins - 1)
    index = np.where(known, inner, n_bins)
    counts = np.bincount(index, minlength=n_bins + 1)
    sums = {
        name: np.bincount(index, weights=flag.astype(np.float64), minlength=n_bins + 1)
        for name, flag in hits
    }
    out = []
    for i in range(n_bins + 1):
        if i == n_bins and counts[i] == 0:
            continue
        lo, hi = (edges[i], edges[i + 1]) if i < n_bins else (math.nan, math.nan)
        entry: dict[str, Any] = {
            "label": _label(lo, hi) if i < n_bins else "unknown",
            "lo": None if math.isnan(lo) else lo,
            "hi": None if math.isinf(hi) or math.isnan(hi) else hi,
            "n": int(counts[i]),
        }
        for name, _ in hits:
            entry[name] = int(sums[name][i])
            entry[f"{name}_rate"] = ratio(sums[name][i], counts[i])
        out.append(entry)
    return out


# -- 2D -----------------------------------------------------------------------------------


def false_positive_kinds(
    detections: Detections,
    is_true: NDArray[np.bool_],
    distance: NDArray,
    truth: GroundTruth,
    camera: int,
) -> dict[str, int]:
    """What each false detection is: ``near_flash`` (within `NEAR_FLASH_PX` of a true
    flash: a fragment), the kind of the artifact whose label radius holds it (``glint``,
    ``foliage``, ``lamp``, …; `pipeline.simulation.ArtifactTruth`), or ``other``
    (noise, compression)."""
    false = np.flatnonzero(~is_true)
    kinds = np.full(len(false), "other", dtype=object)
    near = distance[false] <= NEAR_FLASH_PX
    kinds[near] = "near_flash"
    art = truth.artifacts
    rows = np.flatnonzero(art.camera == camera)
    todo = false[~near]
    if len(rows) and len(todo):
        pts = camera_points(art.u[rows], art.v[rows], truth.width)
        det = camera_points(detections.x[todo], detections.y[todo], truth.width)
        reach = float(art.radius[rows].max())
        span = 10.0 * (truth.width + reach)  # frames far apart in a 4th coordinate
        tree = cKDTree(np.column_stack([pts, art.frame[rows] * span]))
        k = min(8, len(rows))
        dist, idx = tree.query(
            np.column_stack([det, detections.frame[todo] * span]), k=k, distance_upper_bound=reach
        )
        dist, idx = dist.reshape(len(todo), k), idx.reshape(len(todo), k)
        valid = idx < len(rows)
        inside = valid & (dist <= art.radius[rows][np.minimum(idx, len(rows) - 1)])
        first = np.argmax(inside, axis=1)
        hit = inside[np.arange(len(todo)), first]
        owner = rows[np.minimum(idx[np.arange(len(todo)), first], len(rows) - 1)]
        sub = np.flatnonzero(~near)
        kinds[sub[hit]] = art.kind[owner[hit]]
    names, counts = np.unique(kinds.astype(str), return_counts=True)
    return {str(k): int(c) for k, c in zip(names, counts, strict=True)}


def detection_figures(
    detections: Detections, match: DetectionMatch, truth: GroundTruth, camera: int, n_frames: int
) -> dict[str, Any]:
    """Recall (overall, at SNR ≥ `HEADLINE_SNR`, per SNR and range bin), precision,
    rates per frame and false positives by kind for one camera's detections and their
    `match_detections`."""
    flashes = truth.flashes
    snr = flashes.camera_column("snr", camera)[match.truth_rows]
    distance = flashes.camera_column("range", camera)[match.truth_rows]
    mf_snr = flashes.camera_column("snr_mf", camera)[match.truth_rows]
    psf = flashes.camera_column("psf", camera)[match.truth_rows]
    strong = snr >= HEADLINE_SNR
    mf_strong = mf_snr >= HEADLINE_SNR
    n_true = int(match.true_detection.sum())
    return {
        "n_truth": len(match.truth_rows),
        "n_found": int(match.found.sum()),
        "recall": ratio(match.found.sum(), len(match.found)),
        "n_truth_snr_ge5": int(strong.sum()),
        "n_found_snr_ge5": int(match.found[strong].sum()),
        "recall_snr_ge5": ratio(match.found[strong].sum(), strong.sum()),
        "n_truth_mf_snr_ge5": int(mf_strong.sum()),
        "n_found_mf_snr_ge5": int(match.found[mf_strong].sum()),
        "recall_mf_snr_ge5": ratio(match.found[mf_strong].sum(), mf_strong.sum()),
        "n_detections": len(detections),
        "n_true": n_true,
        "precision": ratio(n_true, len(detections)),
        "n_frames": int(n_frames),
        "per_frame": ratio(len(detections), n_frames),
        "false_per_frame": ratio(len(detections) - n_true, n_frames),
        "false_by_kind": false_positive_kinds(
            detections, match.true_detection, match.distance, truth, camera
        ),
        "by_snr": binned(snr, [("found", match.found)], SNR_EDGES),
        "by_mf_snr": binned(mf_snr, [("found", match.found)], SNR_EDGES),
        "by_range_m": binned(distance, [("found", match.found)], RANGE_EDGES_M),
        "by_psf_px_snr_ge5": binned(psf[strong], [("found", match.found[strong])], PSF_EDGES_PX),
        "median_error_px": float(np.median(match.error[match.found]))
        if match.found.any()
        else None,
        "by_error_px": binned(match.error[match.found], [], ERROR_EDGES_PX),
        **flash_event_figures(
            flashes.flash_id[match.truth_rows],
            flashes.in_camera(camera)[0][match.truth_rows],
            snr,
            match.found,
        ),
    }


def flash_event_figures(
    flash_id: NDArray[np.int64],
    frame: NDArray[np.int64],
    snr: NDArray[np.float64],
    found: NDArray[np.bool_],
) -> dict[str, Any]:
    """Recall of whole flashes, and where the missed flash-frames lie along them.

    A biologist counts flashes and times them; a flash lit for 5 frames and found in 3
    is counted, its duration short. Figures, over a set of flash-frames (those visible
    in one camera, or in both for 3D):

    - ``flash_recall_snr_ge5``: the flashes whose brightest frame is at least
      `HEADLINE_SNR` with at least one frame found;
    - ``n_missed_snr_ge5_beside_found``: the missed flash-frames of at least
      `HEADLINE_SNR` within `BESIDE_FRAMES` frames of a found frame of the same flash
      (its rise or fall), of ``n_truth_snr_ge5 - n_found_snr_ge5`` missed in all.

    Parameters
    ----------
    flash_id, frame : ndarray of int64, shape (N,)
        Per true flash-frame: its flash and its frame (in one camera's numbering).
    snr : ndarray of float64, shape (N,)
        Its peak SNR against the sensor noise.
    found : ndarray of bool, shape (N,)
        Whether it was found (a matched detection, or a 3D point within tolerance).
    """
    ids, flash = np.unique(flash_id, return_inverse=True)
    peak = np.full(len(ids), -np.inf)
    np.maximum.at(peak, flash, snr)
    seen = np.bincount(flash, weights=found, minlength=len(ids)) > 0
    strong = peak >= HEADLINE_SNR
    # One integer key per (flash, frame): a found frame d frames away has key + d, and
    # no key ± BESIDE_FRAMES reaches another flash's.
    frame = frame - frame.min(initial=0)
    key = flash * (int(frame.max(initial=0)) + BESIDE_FRAMES + 1) + frame
    found_keys = key[found]
    beside = np.zeros(len(key), dtype=bool)
    for offset in range(1, BESIDE_FRAMES + 1):
        beside |= np.isin(key + offset, found_keys) | np.isin(key - offset, found_keys)
    missed = ~found & (snr >= HEADLINE_SNR)
    return {
        "n_flashes_snr_ge5": int(strong.sum()),
        "n_flashes_found_snr_ge5": int((strong & seen).sum()),
        "flash_recall_snr_ge5": ratio((strong & seen).sum(), strong.sum()),
        "n_missed_snr_ge5_beside_found": int((missed & beside).sum()),
    }


# -- stereo ---------------------------------------------------------------------------------


def stereo_figures(
    match1: DetectionMatch, match2: DetectionMatch, truth: GroundTruth
) -> dict[str, Any]:
    """Flash-frames seen by both cameras that were detected in both (each camera's
    `match_detections`): what triangulation could reconstruct with a perfect
    calibration, an upper bound on 3D recall that does not depend on the delay and pose
    estimates."""
    flashes = truth.flashes
    found = np.zeros((2, len(flashes)), dtype=bool)
    for camera, match in enumerate((match1, match2)):
        found[camera, match.truth_rows[match.found]] = True
    rows = np.flatnonzero(flashes.visible1 & flashes.visible2)
    both = found[0, rows] & found[1, rows]
    snr = np.fmin(flashes.snr1[rows], flashes.snr2[rows])
    strong = snr >= HEADLINE_SNR
    return {
        "n_truth": len(rows),
        "n_found": int(both.sum()),
        "recall": ratio(both.sum(), len(rows)),
        "n_truth_snr_ge5": int(strong.sum()),
        "n_found_snr_ge5": int(both[strong].sum()),
        "recall_snr_ge5": ratio(both[strong].sum(), strong.sum()),
        "by_range_m": binned(flashes.range1[rows], [("found", both)], RANGE_EDGES_M),
        "by_snr": binned(snr, [("found", both)], SNR_EDGES),
    }


# -- 3D -----------------------------------------------------------------------------------


def pair_rows(
    index1: NDArray[np.int64],
    index2: NDArray[np.int64],
    match1: DetectionMatch,
    match2: DetectionMatch,
) -> NDArray[np.int64]:
    """Per triangulated point, the true flash-frame its two detections are both of.

    Parameters
    ----------
    index1, index2 : ndarray of int64
        Rows of each camera's accepted detections (``flashes_cam*.csv``) each point was
        triangulated from (``work/points.npz``).
    match1, match2 : DetectionMatch
        `evaluate.match_detections` of those detections.

    Returns
    -------
    ndarray of int64
        Row of ``truth.flashes`` where both detections match that same flash-frame,
        -1 where either is false or they are of two different flash-frames (a
        mispairing).
    """
    row1 = match1.flash_row[index1]
    row2 = match2.flash_row[index2]
    return np.where((row1 >= 0) & (row1 == row2), row1, -1)


def point_figures(
    xyz: NDArray,
    frame: NDArray,
    truth: GroundTruth,
    range_sd: NDArray | None = None,
    pair_row: NDArray[np.int64] | None = None,
) -> dict[str, Any]:
    """3D recall (within 5 % and 2 % of range), precision, and recall per range bin
    (from camera 1) and per bin of the smaller of the two cameras' peak SNR, and of
    whole flashes (`flash_event_figures`, on that smaller SNR); with the
    points' `range_sd` (metres), how well it describes their range errors
    (`uncertainty_figures`); with each point's `pair_rows`, the same figures for the
    *pairing* whatever the range error (`pair_figures`)."""
    match = match_points(xyz, frame, truth)
    found = match.found(IDENTITY_TOLERANCE)
    found2 = match.found(RANGE_TOLERANCE)
    flashes = truth.flashes
    rows = match.truth_rows
    snr = np.fmin(flashes.snr1[rows], flashes.snr2[rows])
    flags = [("found", found), ("found_within_2pct", found2)]
    paired: dict[str, Any] = {}
    if pair_row is not None:
        found_paired = np.isin(rows, pair_row)
        flags.append(("found_paired", found_paired))
        paired = pair_figures(pair_row, found_paired)
    return (
        {
            "n_truth": len(rows),
            "n_found": int(found.sum()),
            "recall": ratio(found.sum(), len(rows)),
            "n_found_within_2pct": int(found2.sum()),
            "recall_within_2pct": ratio(found2.sum(), len(rows)),
            "n_points": len(frame),
            "n_true": int(match.point_is_true.sum()),
            "precision": ratio(match.point_is_true.sum(), len(frame)),
            "by_range_m": binned(match.true_range, flags, RANGE_EDGES_M),
            "by_snr": binned(snr, flags, SNR_EDGES),
        }
        | flash_event_figures(flashes.flash_id[rows], flashes.frame1[rows], snr, found)
        | uncertainty_figures(xyz, range_sd, match)
        | paired
    )


def pair_figures(pair_row: NDArray[np.int64], found_paired: NDArray[np.bool_]) -> dict[str, Any]:
    """Stereo pairing scored apart from range accuracy.

    * ``n_pair_true`` of the ``n_pair_points`` points were triangulated from two
      detections of one true flash-frame (``pair_precision``), whatever their range
      error: what is left of ``1 - precision`` is range resolution, not false flashes;
    * ``n_found_paired`` of the ``n_truth`` flash-frames seen by both cameras have such
      a point (``pair_recall``): what 3D recall would be if every range were exact.
    """
    n_pair_true = int(np.count_nonzero(pair_row >= 0))
    return {
        "n_pair_points": len(pair_row),
        "n_pair_true": n_pair_true,
        "pair_precision": ratio(n_pair_true, len(pair_row)),
        "n_found_paired": int(found_paired.sum()),
        "pair_recall": ratio(found_paired.sum(), len(found_paired)),
    }


def uncertainty_figures(
    xyz: NDArray, range_sd: NDArray | None, match: PointMatch
) -> dict[str, Any]:
    """How well the points' range standard deviations describe their range errors.

    * ``n_covered`` of the ``n_matched`` points (those with a true flash in their frame)
      are within ``COVERAGE_SDS`` standard deviations of its range (``coverage``: 0.95
      for a calibrated Gaussian error; mismatched flashes count as misses);
    * ``n_sure`` points have ``range_sd / range ≤ SURE_RELATIVE_SD``, ``n_sure_true`` of
      them are true (``precision_sure``): what a user keeping only those gets.

    Empty without a finite `range_sd` for every point (results of earlier releases).
    """
    if range_sd is None or not np.isfinite(range_sd).all():
        return {}
    point_range = np.linalg.norm(xyz, axis=1)
    matched = np.isfinite(match.point_range)
    error = np.abs(point_range[matched] - match.point_range[matched])
    n_covered = int(np.count_nonzero(error <= COVERAGE_SDS * range_sd[matched]))
    sure = sure_of_range(range_sd, point_range)
    n_sure_true = int((sure & match.point_is_true).sum())
    return {
        "n_matched": int(matched.sum()),
        "n_covered": n_covered,
        "coverage": ratio(n_covered, int(matched.sum())),
        "n_sure": int(sure.sum()),
        "n_sure_true": n_sure_true,
        "precision_sure": ratio(n_sure_true, int(sure.sum())),
    }


# -- a run ---------------------------------------------------------------------------------


# -- the acceptance cut ----------------------------------------------------------------------


def cut_figures(
    candidates: Detections,
    probability: NDArray[np.floating],
    truth: GroundTruth,
    camera: int,
    cuts: Sequence[float],
) -> list[dict[str, Any]]:
    """The 2D headline figures of one camera had the evidence model accepted the
    candidates of flash probability ≥ each cut.

    The trade that ``acceptance.evidence_threshold`` makes, read from one run's
    per-candidate probabilities (``work/acceptance_cam*.npz``) without running it again:
    at the run's own cut the figures are those of its accepted detections, since these
    are the candidates of probability at or above it.

    Parameters
    ----------
    candidates : Detections
        Every candidate of the camera (``work/candidates_cam*.npz``).
    probability : ndarray, shape (N,)
        The evidence model's flash probability of each candidate.
    truth : GroundTruth
    camera : int
        1 or 2.
    cuts : sequence of float
        Probability cuts, in [0, 1].

    Returns
    -------
    list of dict
        Per cut: ``cut``, the counts and ratio of recall at peak SNR ≥ `HEADLINE_SNR`
        (``n_truth_snr_ge5``, ``n_found_snr_ge5``, ``recall_snr_ge5``), precision
        (``n_detections``, ``n_true``, ``precision``) and ``f1_snr_ge5``, the harmonic
        mean of the two.
    """
    snr = truth.flashes.camera_column("snr", camera)
    out = []
    for cut in cuts:
        accepted = candidates.select(np.asarray(probability) >= cut)
        match = match_detections(accepted, truth, camera)
        strong = snr[match.truth_rows] >= HEADLINE_SNR
        n_true = int(match.true_detection.sum())
        entry = {
            "cut": float(cut),
            "n_truth_snr_ge5": int(strong.sum()),
            "n_found_snr_ge5": int(match.found[strong].sum()),
            "recall_snr_ge5": ratio(match.found[strong].sum(), strong.sum()),
            "n_detections": len(accepted),
            "n_true": n_true,
            "precision": ratio(n_true, len(accepted)),
        }
        out.append(_with_f1(entry))
    return out


def _with_f1(entry: dict[str, Any]) -> dict[str, Any]:
    recall, precision = entry["recall_snr_ge5"], entry["precision"]
    f1 = None
    if recall is not None and precision is not None and recall + precision > 0:
        f1 = 2 * recall * precision / (recall + precision)
    return entry | {"f1_snr_ge5": f1}


def _cuts_of_run(
    results: Path, candidates: dict[int, Detections], truth: GroundTruth, cuts: Sequence[float]
) -> dict[str, list[dict[str, Any]] | None] | None:
    """`cut_figures` of both cameras of a run folder; a camera is None where the rules
    decided (no probabilities) or its files are missing."""
    if not cuts:
        return None
    out: dict[str, list[dict[str, Any]] | None] = {}
    for camera in artifacts.CAMERAS:
        path = results / artifacts.ACCEPTANCE_NPZ.format(camera=camera)
        figures = None
        if camera in candidates and path.is_file():
            with np.load(path) as saved:
                probability = saved["probability"]
            if len(probability) == len(candidates[camera]) and not np.isnan(probability).all():
                figures = cut_figures(candidates[camera], probability, truth, camera, cuts)
        out[f"cam{camera}"] = figures
    return out


def score_run(results: Path, truth: GroundTruth, cuts: Sequence[float] = ()) -> dict[str, Any]:
    """Every figure of one run folder against its truth (what is missing is None);
    with `cuts`, also `cut_figures` per camera (``cuts``)."""
    cameras: dict[str, Any] = {}
    loaded: dict[str, dict[int, Detections]] = {"accepted": {}, "candidates": {}}
    for camera in artifacts.CAMERAS:
        flashes = results / artifacts.flashes_name(camera)
        if flashes.is_file():
            loaded["accepted"][camera] = Detections.from_csv(flashes)
        candidates = results / artifacts.candidates_name(camera)
        if candidates.is_file():
            loaded["candidates"][camera] = Detections.from_npz(candidates)
    # Each camera's detections matched once, for its figures, the stereo ones and pairing.
    matches = {
        kind: {camera: match_detections(d, truth, camera) for camera, d in found.items()}
        for kind, found in loaded.items()
    }
    for camera in artifacts.CAMERAS:
        n_frames = truth.n_frames1 if camera == 1 else truth.n_frames2
        cameras[f"cam{camera}"] = {
            kind: detection_figures(found[camera], matches[kind][camera], truth, camera, n_frames)
            if camera in found
            else None
            for kind, found in loaded.items()
        }
    stereo = {
        kind: stereo_figures(match[1], match[2], truth) if len(match) == 2 else None
        for kind, match in matches.items()
    }
    points = None
    trajectories = results / artifacts.TRAJECTORIES_CSV
    if trajectories.is_file():
        table = read_trajectories(trajectories)
        xyz = np.column_stack([table["x"], table["y"], table["z"]])
        sd = table.get("range_sd_m")
        pairs = _pair_rows_of_run(results, matches["accepted"], len(xyz))
        points = point_figures(xyz, np.asarray(table["frame"]), truth, sd, pairs)
    return {
        "cameras": cameras,
        "stereo": stereo,
        "points_3d": points,
        "cuts": _cuts_of_run(results, loaded["candidates"], truth, cuts),
    }


def _pair_rows_of_run(
    results: Path, accepted: dict[int, DetectionMatch], n_points: int
) -> NDArray[np.int64] | None:
    """`pair_rows` of a run's points (``work/points.npz``, one row per line of
    ``trajectories.csv``, same order); None without them or both cameras' detections."""
    path = results / artifacts.POINTS_NPZ
    if len(accepted) < 2 or not path.is_file():
        return None
    points = load_points(path)
    if len(points) != n_points:  # another run's points: nothing to say about these
        return None
    return pair_rows(points.index1, points.index2, accepted[1], accepted[2])


# -- pooling -------------------------------------------------------------------------------

_RATIOS = {
    "recall": ("n_found", "n_truth"),
    "recall_snr_ge5": ("n_found_snr_ge5", "n_truth_snr_ge5"),
    "recall_mf_snr_ge5": ("n_found_mf_snr_ge5", "n_truth_mf_snr_ge5"),
    "flash_recall_snr_ge5": ("n_flashes_found_snr_ge5", "n_flashes_snr_ge5"),
    "recall_within_2pct": ("n_found_within_2pct", "n_truth"),
    "precision": ("n_true", None),  # denominator: n_detections or n_points
    "per_frame": ("n_detections", "n_frames"),
    "coverage": ("n_covered", "n_matched"),
    "precision_sure": ("n_sure_true", "n_sure"),
    "pair_precision": ("n_pair_true", "n_pair_points"),
    "pair_recall": ("n_found_paired", "n_truth"),
}


def _pool_figures(parts: list[dict[str, Any] | None]) -> dict[str, Any] | None:
    """Sum the counts of several runs' figures (same layout) and recompute the ratios."""
    present = [p for p in parts if p is not None]
    if not present:
        return None
    out: dict[str, Any] = {}
    for key, value in present[0].items():
        if isinstance(value, bool) or value is None or isinstance(value, float):
            continue
        if isinstance(value, int):
            out[key] = sum(int(p.get(key) or 0) for p in present)
        elif key == "false_by_kind":
            kinds: dict[str, int] = {}
            for p in present:
                for kind, count in p[key].items():
                    kinds[kind] = kinds.get(kind, 0) + count
            out[key] = dict(sorted(kinds.items()))
        elif isinstance(value, list):
            out[key] = _pool_bins([p[key] for p in present])
    for name, (num, den) in _RATIOS.items():
        if name in present[0] and num in out:
            denominator = den or ("n_detections" if "n_detections" in out else "n_points")
            out[name] = ratio(out[num], out.get(denominator, 0))
    if "n_detections" in out and "n_frames" in out:
        out["false_per_frame"] = ratio(out["n_detections"] - out["n_true"], out["n_frames"])
    return out


def _pool_bins(parts: list[list[dict[str, Any]]]) -> list[dict[str, Any]]:
    merged: dict[str, dict[str, Any]] = {}
    for bins in parts:
        for entry in bins:
            into = merged.setdefault(
                entry["label"],
                {k: v for k, v in entry.items() if k in ("label", "lo", "hi")} | {"n": 0},
            )
            into["n"] += entry["n"]
            for key, value in entry.items():
                if key not in ("label", "lo", "hi", "n") and not key.endswith("_rate"):
                    into[key] = into.get(key, 0) + value
    out = []
    for entry in merged.values():
        for key in [k for k in entry if k not in ("label", "lo", "hi", "n")]:
            entry[f"{key}_rate"] = ratio(entry[key], entry["n"])
        out.append(entry)
    return sorted(out, key=lambda e: (e["lo"] is None, e["lo"] or 0.0))


def pool(runs: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """Pool the figures of several runs (e.g. the seeds of a scenario): counts add up,
    ratios are recomputed from the sums (not averaged)."""
    runs = [r for r in runs if r.get("cameras")]
    cameras = {
        cam: {
            kind: _pool_figures([r["cameras"][cam][kind] for r in runs])
            for kind in ("accepted", "candidates")
        }
        for cam in ("cam1", "cam2")
    }
    stereo = {
        kind: _pool_figures([(r.get("stereo") or {}).get(kind) for r in runs])
        for kind in ("accepted", "candidates")
    }
    return {
        "n_runs": len(runs),
        "seeds": [r.get("seed") for r in runs],
        "cameras": cameras,
        "stereo": stereo,
        "points_3d": _pool_figures([r["points_3d"] for r in runs]),
        "cuts": _pool_cuts([r.get("cuts") for r in runs]),
    }


def _pool_cuts(
    parts: list[dict[str, list[dict[str, Any]] | None] | None],
) -> dict[str, list[dict[str, Any]] | None] | None:
    """Pool `cut_figures` cut by cut, over the runs scored at the same cuts."""
    present = [p for p in parts if p is not None]
    if not present:
        return None
    out: dict[str, list[dict[str, Any]] | None] = {}
    for cam in ("cam1", "cam2"):
        runs = [figures for p in present if (figures := p.get(cam))]
        cuts = {tuple(e["cut"] for e in r) for r in runs}
        if not runs or len(cuts) != 1:
            out[cam] = None
            continue
        out[cam] = [
            _with_f1({"cut": entries[0]["cut"], **(_pool_figures(list(entries)) or {})})
            for entries in zip(*runs, strict=True)
        ]
    return out


# -- text ----------------------------------------------------------------------------------


def _f(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _pair(entry: dict[str, Any], kind: str, key: str, digits: int = 2) -> str:
    values = []
    for cam in ("cam1", "cam2"):
        figures = entry["cameras"][cam][kind]
        values.append(_f(None if figures is None else figures.get(key), digits))
    return "/".join(values)


def _range_recall(points: dict[str, Any] | None, key: str = "found_rate") -> str:
    if points is None:
        return "-"
    return " / ".join(_f(b.get(key)) for b in points["by_range_m"] if b["label"] != "unknown")


@dataclass(frozen=True)
class Row:
    name: str
    entry: dict[str, Any]


def format_table(rows: list[Row]) -> str:
    """The summary table: one line per run (and per pooled scenario).

    Columns: 2D recall of the accepted detections (all, at peak SNR ≥ 5, and at
    matched-filter SNR ≥ 5), the candidates' recall at SNR ≥ 5 (before acceptance),
    the recall of whole flashes of peak SNR ≥ 5 (`flash_event_figures`), accepted
    precision, candidates per frame, the share of flash-frames seen by both
    cameras that both detected (``2cam``: 3D recall with a perfect calibration), 3D
    recall (5 % of range; 2 % in brackets) and precision, the 3D recall of whole flashes
    of smaller peak SNR ≥ 5 (at least one frame within 5 %), the recall and precision of
    the stereo pairing whatever the range error (``pair``, `pair_figures`), the
    precision of the points whose range is sure within `SURE_RELATIVE_SD` with the share
    of points they are, the coverage of the range errors by twice the points' standard
    deviations, 3D recall per range bin, the run's delay error (frames) and rotation
    error (degrees), which explain a collapsed 3D recall.
    """
    header = (
        f"{'night':<24} {'recall c1/c2':>12} {'SNR>=5 c1/c2':>12} {'mf>=5 c1/c2':>11} "
        f"{'cand>=5 c1/c2':>13} {'flash>=5 c1/c2':>14} "
        f"{'prec c1/c2':>10} {'cand/frame':>10} {'2cam':>4} {'3D rec':>6} {'(2%)':>6} "
        f"{'3D prec':>7} {'3D flash>=5':>11} {'pair rec/prec':>13} "
        f"{'sure: prec share':>16} {'cov':>4} "
        f"{'dk':>3} {'rot':>5}  3D recall by range 0-5/5-8/8-20/>=20 m"
    )
    lines = [header, "-" * len(header)]
    for row in rows:
        e = row.entry
        points = e.get("points_3d")
        stereo = (e.get("stereo") or {}).get("accepted")
        accuracy = e.get("accuracy") or {}
        delay = accuracy.get("delay_error_frames")
        rotation = accuracy.get("rotation_error_deg")
        lines.append(
            f"{row.name:<24} {_pair(e, 'accepted', 'recall'):>12} "
            f"{_pair(e, 'accepted', 'recall_snr_ge5'):>12} "
            f"{_pair(e, 'accepted', 'recall_mf_snr_ge5'):>11} "
            f"{_pair(e, 'candidates', 'recall_snr_ge5'):>13} "
            f"{_pair(e, 'accepted', 'flash_recall_snr_ge5'):>14} "
            f"{_pair(e, 'accepted', 'precision'):>10} "
            f"{_pair(e, 'candidates', 'per_frame', 1):>10} "
            f"{_f(stereo and stereo['recall']):>4} "
            f"{_f(points and points['recall']):>6} "
            f"({_f(points and points['recall_within_2pct'])}) "
            f"{_f(points and points['precision']):>7} "
            f"{_f(points and points['flash_recall_snr_ge5']):>11} {_pairing(points):>13} "
            f"{_sure(points):>16} "
            f"{_f(points and points.get('coverage')):>4} "
            f"{'-' if delay is None else delay:>3} {_f(rotation, 1):>5}  "
            f"{_range_recall(points)}"
        )
    return "\n".join(lines)


def _pairing(points: dict[str, Any] | None) -> str:
    """Recall and precision of the stereo pairing, whatever the range error."""
    if not points or points.get("n_pair_points") is None:
        return "-"
    return f"{_f(points['pair_recall'])}/{_f(points['pair_precision'])}"


def _sure(points: dict[str, Any] | None) -> str:
    """Precision of the points sure of their range, and their share of all points."""
    if not points or points.get("n_sure") is None:
        return "-"
    return f"{_f(points['precision_sure'])} {_f(ratio(points['n_sure'], points['n_points']))}"


def format_cuts(rows: list[Row]) -> str:
    """Per run (and pooled scenario), the 2D figures at each evidence-model cut
    (`cut_figures`): recall at peak SNR ≥ 5, precision and their F1 per camera, and the
    true and false detections of both cameras."""
    header = (
        f"{'night':<24} {'cut':>5} {'SNR>=5 c1/c2':>12} {'prec c1/c2':>10} {'F1 c1/c2':>9} "
        f"{'true / false':>14}"
    )
    lines = ["2D at each evidence-model cut (candidates of flash probability >= cut)", header]
    lines.append("-" * len(header))
    for row in rows:
        cuts = row.entry.get("cuts") or {}
        cameras = [cuts.get(cam) for cam in ("cam1", "cam2")]
        present = [c for c in cameras if c]
        if not present:
            lines.append(f"{row.name:<24} no evidence-model probabilities (the rules decided)")
            continue
        for i, cut in enumerate(e["cut"] for e in present[0]):
            at = [c[i] if c else {} for c in cameras]
            recall, precision, f1 = (
                "/".join(_f(e.get(key)) for e in at)
                for key in ("recall_snr_ge5", "precision", "f1_snr_ge5")
            )
            true = sum(e.get("n_true", 0) for e in at)
            false = sum(e.get("n_detections", 0) for e in at) - true
            lines.append(
                f"{row.name:<24} {cut:>5.3g} {recall:>12} {precision:>10} {f1:>9} "
                f"{f'{true:,} / {false:,}':>14}"
            )
    return "\n".join(lines)


def format_bins(name: str, entry: dict[str, Any]) -> str:
    """Recall per SNR and range bin, accepted and candidates, both cameras."""
    lines = [f"{name}: recall by bin (accepted | candidates; n = true flash-frames)"]
    axes = (
        ("by_snr", "peak SNR"),
        ("by_mf_snr", "matched-filter SNR"),
        ("by_range_m", "range m"),
        ("by_psf_px_snr_ge5", "spot sigma px (>= 5 sigma)"),
    )
    for axis, title in axes:
        for cam in ("cam1", "cam2"):
            acc = entry["cameras"][cam]["accepted"]
            cand = entry["cameras"][cam]["candidates"]
            if acc is None and cand is None:
                continue
            bins = (acc or cand)[axis]
            cand_bins = {b["label"]: b for b in cand[axis]} if cand else {}
            cells = []
            for b in bins:
                c = cand_bins.get(b["label"], {})
                cells.append(
                    f"{b['label']}: {_f(b['found_rate']) if acc else '-'}"
                    f" | {_f(c.get('found_rate'))} (n={b['n']})"
                )
            lines.append(f"  {title:<9} {cam}  " + "   ".join(cells))
    stereo = (entry.get("stereo") or {}).get("accepted")
    if stereo is not None:
        cells = [f"{b['label']}: {_f(b['found_rate'])} (n={b['n']})" for b in stereo["by_range_m"]]
        lines.append("  both cameras by range m  " + "   ".join(cells))
    points = entry.get("points_3d")
    if points is not None:
        cells = [
            f"{b['label']}: {_f(b['found_rate'])} | {_f(b.get('found_paired_rate'))} (n={b['n']})"
            for b in points["by_snr"]
        ]
        lines.append("  3D by min peak SNR (within 5 % | paired)  " + "   ".join(cells))
    for cam in ("cam1", "cam2"):
        acc = entry["cameras"][cam]["accepted"]
        if acc is not None:
            found = sum(b["n"] for b in acc["by_error_px"])
            cells = [f"{b['label']}: {_f(ratio(b['n'], found))}" for b in acc["by_error_px"]]
            lines.append(f"  position error px {cam}  " + "   ".join(cells))
    for cam in ("cam1", "cam2"):
        acc = entry["cameras"][cam]["accepted"]
        if acc is not None:
            missed = acc["n_truth_snr_ge5"] - acc["n_found_snr_ge5"]
            lines.append(
                f"  missed >= 5 sigma {cam}  {missed}, of which "
                f"{acc['n_missed_snr_ge5_beside_found']} within {BESIDE_FRAMES} frames "
                "of a found frame of the same flash"
            )
    for cam in ("cam1", "cam2"):
        acc = entry["cameras"][cam]["accepted"]
        cand = entry["cameras"][cam]["candidates"]
        parts = []
        for kind, figures in (("accepted", acc), ("candidates", cand)):
            if figures:
                counts = ", ".join(f"{k} {v}" for k, v in figures["false_by_kind"].items())
                parts.append(f"{kind}: {counts or 'none'}")
        if parts:
            lines.append(f"  false positives {cam}  " + "; ".join(parts))
    return "\n".join(lines)


def finite(value: Any) -> Any:
    """``value`` (nested dicts and lists) with NaN and infinities as None: strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value


def tolerances() -> dict[str, float]:
    return {
        "detection_px": DETECTION_TOLERANCE_PX,
        "identity_fraction_of_range": IDENTITY_TOLERANCE,
        "range_fraction": RANGE_TOLERANCE,
        "near_flash_px": NEAR_FLASH_PX,
        "headline_snr": HEADLINE_SNR,
    }


def bins_description() -> dict[str, list[float | None]]:
    def edges(values: Sequence[float]) -> list[float | None]:
        return [None if math.isinf(v) else v for v in values]

    return {
        "snr": edges(SNR_EDGES),
        "mf_snr": edges(SNR_EDGES),
        "range_m": edges(RANGE_EDGES_M),
        "psf_px_snr_ge5": edges(PSF_EDGES_PX),
        "error_px": edges(ERROR_EDGES_PX),
    }
