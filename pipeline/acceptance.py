"""Which flash candidates are flashes: every kind of evidence, weighed in two steps.

Before step 1, `refined` moves each candidate to a straight-line fit through its light
curve's positions (`pipeline.refine`): the delay, the pose and the triangulation all
start from those positions.

Step 1, per camera (`assess`), from the candidate alone:

* **flicker** — its spot lights up in too many frames of a window (`pipeline.flicker`):
  moonlight through leaves, a twinkling reflection;
* **light curve** — its spot stays lit for longer than a flash (`steady_frames`): a
  flash rises and falls within ~2–15 frames at 60 fps, a lamp or a glint held by the
  wind does not. The frames where tracking found only a faint peak at the spot (between
  ``tracking.lit_threshold`` and the seed level) count as lit: a glint is a candidate
  only at its brightest moments, and faintly lit between them;
* **recurrence** — its spot was as bright for a good share of the seconds before
  (`pipeline.recurrence`, measured while tracking): foliage swinging the sky or a
  glint in and out of a pixel, where a firefly only passes;
* **classifier** — the patch classifier's probability is below ``doubt_probability``;
* otherwise the candidate is **confident** when the classifier accepts it (probability
  at or above its threshold) *and* it stands ``confident_snr`` σ above the noise
  (``single_frame_snr`` if its spot is lit in that frame only), and **doubtful** if
  not. The delay and the pose are estimated from confident flashes only.

Step 2, across the cameras (`confirm`), once the delay and the pose are known: a
doubtful candidate is a flash when it matches a candidate of the other camera within
the triangulation gates and either its light curve is matched with the same light curve
of the other camera in at least ``min_streak`` frames, one of which stands
``streak_peak_snr`` σ above the noise in both cameras, or both candidates stand
``stereo_snr`` σ above the noise. Noise, glints and faint artifacts almost never light
the same two spots of the two cameras at a consistent bearing frame after frame, nor
does noise reach 6 σ in both at once; a faint distant firefly does. A 3D streak alone
is not evidence: candidates of different spots lighting up one after another can lie
within a streak link of each other in 3D (wind-shaken foliage, more so at higher
resolution), and a far flash's depth noise (at 15 m and 640 px a tenth of a pixel is
0.2 m of depth) breaks the links of a true one.

Verdicts are small integers (`Verdict`), stored per candidate row.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from pipeline.detections import Detections
from pipeline.flicker import candidate_duty, flickering, spot_tree
from pipeline.geometry import Pose
from pipeline.params import AcceptanceParams, FlickerParams, TriangulationParams
from pipeline.refine import refine_positions
from pipeline.triangulate import triangulate

BoolArray = NDArray[np.bool_]


class Verdict(IntEnum):
    """What the evidence says about one candidate."""

    CONFIDENT = 0
    DOUBTFUL = 1
    FLICKER = 2
    STEADY = 3
    CLASSIFIER = 4
    RECURRENT = 5


@dataclass(frozen=True)
class Evidence:
    """Per-candidate evidence of one camera (aligned with its candidates).

    Attributes
    ----------
    verdict : ndarray of int8
        `Verdict` of step 1.
    lit_frames : ndarray of int64
        Frames its spot stays lit (the light curve's length around it).
    chain : ndarray of intp
        Its light curve (`spot_chains` label): which candidates are the same lit spot.
    flicker_duty : ndarray of float64, or None
        Its `pipeline.flicker.flicker_duty`; None where it was not measured (imported
        detections, the baseline, evidence of earlier releases).
    key_frames : ndarray of int64, or None
        Not per candidate: the camera's frames the encoder coded whole
        (`pipeline.video.Frame.key`). Their grain is renewed at once, so both cameras
        burst with speckle at the same frame indices, which `pipeline.sync` must not
        take for a delay. None where unknown (imported detections, earlier releases).
    """

    verdict: NDArray[np.int8]
    lit_frames: NDArray[np.int64]
    chain: NDArray[np.intp]
    flicker_duty: NDArray[np.float64] | None = None
    key_frames: NDArray[np.int64] | None = None

    def __len__(self) -> int:
        return len(self.verdict)

    @property
    def confident(self) -> BoolArray:
        return np.asarray(self.verdict == Verdict.CONFIDENT)

    @property
    def plausible(self) -> BoolArray:
        """Confident or doubtful: what stereo confirmation may use."""
        return np.asarray(self.verdict <= Verdict.DOUBTFUL)

    def counts(self) -> dict[str, int]:
        """Candidates per verdict, by lower-case verdict name."""
        found = np.bincount(self.verdict, minlength=len(Verdict))
        return {v.name.lower(): int(found[v]) for v in Verdict}

    def save(self, path: str | Path) -> None:
        arrays: dict[str, Any] = {
            "verdict": self.verdict,
            "lit_frames": self.lit_frames,
            "chain": self.chain,
        }
        if self.flicker_duty is not None:
            arrays["flicker_duty"] = self.flicker_duty
        if self.key_frames is not None:
            arrays["key_frames"] = self.key_frames
        np.savez_compressed(path, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> Evidence:
        with np.load(path) as data:
            verdict = data["verdict"]
            # Evidence of earlier releases has no chains: each candidate its own.
            chain = data["chain"] if "chain" in data else np.arange(len(verdict))
            duty = data.get("flicker_duty")
            return cls(verdict, data["lit_frames"], chain, duty, data.get("key_frames"))

    @classmethod
    def imported(cls, detections: Detections, width: int, params: AcceptanceParams) -> Evidence:
        """Evidence for detections made elsewhere: confident unless their SNR says faint.

        Rows below ``params.confident_snr`` are doubtful, and stereo can confirm them
        through their light curves (`spot_chains` within ``params.radius_deg``); rows
        without an SNR (NaN) are taken as the flashes they were exported as.
        """
        faint = detections.snr < params.confident_snr  # False for NaN
        verdict = np.where(faint, Verdict.DOUBTFUL, Verdict.CONFIDENT).astype(np.int8)
        chain = spot_chains(detections.frame, detections.x, detections.y, width, params.radius_deg)
        return cls(verdict=verdict, lit_frames=steady_frames(detections.frame, chain), chain=chain)


def spot_chains(
    frame: NDArray[np.integer],
    x: NDArray[np.floating],
    y: NDArray[np.floating],
    width: int,
    radius_deg: float,
) -> NDArray[np.intp]:
    """Light-curve chains: the candidates of one lit spot in consecutive frames.

    Candidates in the same or consecutive frames within `radius_deg` of each other
    (Chebyshev, in pixels of that angle, wrapping at the 360° seam) are chained.

    Parameters
    ----------
    frame : ndarray of int, shape (N,)
        0-based frame of each candidate.
    x, y : ndarray of float, shape (N,)
        Pixel coordinates (DESIGN.md convention), ``0 <= x < width``.
    width : int
        Frame width in pixels (360° of azimuth).
    radius_deg : float
        Neighbourhood radius, degrees.

    Returns
    -------
    ndarray of intp, shape (N,)
        Chain label of each candidate, ``0 .. n_chains − 1``.
    """
    n = len(frame)
    if n == 0:
        return np.zeros(0, np.intp)
    # Consecutive frames are 1 apart in time, frames further apart are not neighbours.
    tree = spot_tree(np.asarray(frame, dtype=np.float64), x, y, width, radius_deg)
    pairs = tree.query_pairs(r=1.0, p=np.inf, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.intp)


def steady_frames(frame: NDArray[np.integer], chain: NDArray[np.integer]) -> NDArray[np.int64]:
    """How many frames each candidate's spot stays lit without a break.

    Parameters
    ----------
    frame : ndarray of int, shape (N,)
        0-based frame of each candidate.
    chain : ndarray of int, shape (N,)
        Its light-curve chain (`spot_chains`).

    Returns
    -------
    ndarray of int64, shape (N,)
        Frames from the first to the last of the candidate's chain, inclusive.
    """
    if len(frame) == 0:
        return np.zeros(0, np.int64)
    first = np.full(chain.max() + 1, np.iinfo(np.int64).max)
    last = np.full(chain.max() + 1, np.iinfo(np.int64).min)
    np.minimum.at(first, chain, frame)
    np.maximum.at(last, chain, frame)
    return (last - first + 1)[chain]


def assess(
    candidates: Detections,
    width: int,
    fps: float,
    threshold: float | None,
    params: AcceptanceParams,
    flicker: FlickerParams,
    faint: Detections | None = None,
) -> Evidence:
    """Step 1: the verdict on each candidate of one camera from its own evidence.

    Parameters
    ----------
    candidates : Detections
        Every candidate of the camera (with ``flash_probability`` and ``snr``).
    width : int
        Frame width in pixels.
    fps : float
        Frames per second.
    threshold : float or None
        The classifier's acceptance threshold; None when no classifier ran.
    params : AcceptanceParams
        Levels of the evidence.
    flicker : FlickerParams
        The flicker test.
    faint : Detections, optional
        The camera's faint peaks (`pipeline.tracking.TrackingResult.faint_peaks`):
        spots lit too faintly to be candidates. They join the light curves (so a
        candidate's chain and lit frames include them); they get no verdict, and
        neither the flicker duty nor the one-frame rule counts them (grain and sway
        light them around true flashes too).

    Returns
    -------
    Evidence
        With ``params.enabled`` false, every candidate is confident (the background-
        subtraction baseline).
    """
    n = len(candidates)
    if not params.enabled:
        return Evidence(np.zeros(n, np.int8), np.ones(n, np.int64), np.arange(n))
    # Candidates first: rows [:n] of everything computed on `spots` are theirs.
    spots = candidates if faint is None else Detections.concat([candidates, faint])
    all_chains = spot_chains(spots.frame, spots.x, spots.y, width, params.radius_deg)
    chain = all_chains[:n]
    lit = steady_frames(spots.frame, all_chains)[:n]
    probability = candidates.flash_probability
    # NaN: no SNR to doubt. A spot that is a candidate in one frame only is as likely
    # grain (faint peaks around it do not count: grain makes them too).
    one_frame = steady_frames(candidates.frame, chain) == 1
    needed = np.where(one_frame, params.single_frame_snr, params.confident_snr)
    snr_ok = ~(candidates.snr < needed)
    if threshold is None:
        unlikely = np.zeros(n, bool)
        likely = np.ones(n, bool)
    else:
        unlikely = probability < params.doubt_probability
        likely = probability >= threshold
    verdict = np.where(likely & snr_ok, Verdict.CONFIDENT, Verdict.DOUBTFUL)
    verdict = np.where(unlikely, Verdict.CLASSIFIER, verdict)
    duty = candidate_duty(candidates, width, fps, flicker)
    verdict = np.where(flickering(duty, flicker), Verdict.FLICKER, verdict)
    # A spot lit without a break also flickers by the duty measure; say the specific why.
    verdict = np.where(lit > params.max_flash_s * fps, Verdict.STEADY, verdict)
    recurrent = candidates.recurrence >= params.max_recurrence  # False for NaN
    verdict = np.where(recurrent & (verdict <= Verdict.DOUBTFUL), Verdict.RECURRENT, verdict)
    return Evidence(verdict.astype(np.int8), lit, chain, duty)


def refined(candidates: Detections, width: int, fps: float, params: AcceptanceParams) -> Detections:
    """Candidates with positions refined along their light curves (`pipeline.refine`).

    Each fit spans ``params.position_window_s`` on either side and weighs every frame
    by its SNR² (the position error of a spot falls as 1 / SNR); rows without an SNR
    weigh as 1 σ.
    """
    half_window = round(params.position_window_s * fps)
    if half_window < 1 or len(candidates) == 0:
        return candidates
    chain = spot_chains(candidates.frame, candidates.x, candidates.y, width, params.radius_deg)
    snr = np.nan_to_num(np.maximum(candidates.snr.astype(np.float64), 1.0), nan=1.0)
    x, y = refine_positions(
        candidates.frame, candidates.x, candidates.y, snr**2, chain, width, half_window
    )
    return candidates.with_positions(x, y)


@dataclass(frozen=True)
class Confirmation:
    """Step 2's outcome: which candidates of each camera are flashes."""

    accepted1: BoolArray
    accepted2: BoolArray
    stereo1: BoolArray
    stereo2: BoolArray


def confirm(
    candidates: tuple[Detections, Detections],
    evidence: tuple[Evidence, Evidence],
    delay_frames: int,
    pose: Pose,
    width: int,
    separation_m: float,
    params: AcceptanceParams,
    triangulation: TriangulationParams,
) -> Confirmation:
    """Step 2: accept the confident candidates and the doubtful ones stereo confirms.

    Parameters
    ----------
    candidates, evidence : pairs (camera 1, camera 2)
        Every candidate of each camera and its step-1 evidence.
    delay_frames : int
        Camera-1 frame ``k`` is camera-2 frame ``k + delay_frames``.
    pose : Pose
        Camera 2 relative to camera 1 (unit translation).
    width : int
        Frame width in pixels.
    separation_m : float
        Camera separation, metres.
    params : AcceptanceParams
        ``min_streak``, ``streak_peak_snr``, ``stereo_snr``, ``stereo_max_gap_deg`` and
        ``anchored``.
    triangulation : TriangulationParams
        The gates of the matches.

    Returns
    -------
    Confirmation
        ``accepted`` masks (confident or confirmed) and ``stereo`` masks (the doubtful
        candidates confirmed), aligned with each camera's candidates.
    """
    (det1, det2), (ev1, ev2) = candidates, evidence
    confirmed = [np.zeros(len(det1), bool), np.zeros(len(det2), bool)]
    if params.enabled and params.stereo:
        rows1, rows2 = np.flatnonzero(ev1.plausible), np.flatnonzero(ev2.plausible)
        gates = stereo_gates(params, triangulation)
        points = triangulate(
            det1.select(rows1), det2.select(rows2), delay_frames, pose, width, separation_m, gates
        )
        weaker = np.fmin(det1.snr[rows1[points.index1]], det2.snr[rows2[points.index2]])
        # The same two light curves matched frame after frame are one flash seen by
        # both cameras. Points of other spots that only happen to lie close in 3D in
        # consecutive frames are not (a 3D streak is no evidence of its own), and a far
        # flash's depth noise breaks 3D links anyway.
        pair = _pair_groups(ev1.chain[rows1[points.index1]], ev2.chain[rows2[points.index2]])
        length, peak = _pair_statistics(pair, np.nan_to_num(weaker, nan=np.inf))
        # A flash rises to a peak; wind-shaken leaves can agree frame after frame too,
        # but stay faint.
        rises = (length >= params.min_streak) & (peak >= params.streak_peak_snr)
        good = rises | ~(weaker < params.stereo_snr)
        if params.anchored:
            sure = ev1.confident[rows1[points.index1]] | ev2.confident[rows2[points.index2]]
            anchored = np.zeros(len(points), bool)
            anchored[pair[sure]] = True
            good &= anchored[pair]
        confirmed[0][rows1[points.index1[good]]] = True
        confirmed[1][rows2[points.index2[good]]] = True
    # Only plausible rows were matched, so the confirmed non-confident ones are doubtful.
    stereo1 = confirmed[0] & ~ev1.confident
    stereo2 = confirmed[1] & ~ev2.confident
    return Confirmation(
        accepted1=ev1.confident | stereo1,
        accepted2=ev2.confident | stereo2,
        stereo1=stereo1,
        stereo2=stereo2,
    )


def stereo_gates(
    params: AcceptanceParams, triangulation: TriangulationParams
) -> TriangulationParams:
    """The triangulation gates of a stereo match that counts as evidence: the ray gap at
    most ``params.stereo_max_gap_deg`` (and the triangulation's own limit)."""
    return triangulation.model_copy(
        update={"max_gap_deg": min(triangulation.max_gap_deg, params.stereo_max_gap_deg)}
    )


def light_curve_pairs(
    chain1: NDArray[np.integer], chain2: NDArray[np.integer], weaker: NDArray[np.floating]
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Per stereo match, of the pair of light curves it joins (camera 1's `chain1`,
    camera 2's `chain2`): how many matches join the same two, and the largest `weaker`
    (the fainter camera's SNR) among them.

    The same two light curves matched frame after frame are one flash seen by both
    cameras.
    """
    return _pair_statistics(_pair_groups(chain1, chain2), weaker)


def _pair_statistics(
    group: NDArray[np.intp], weaker: NDArray[np.floating]
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """`light_curve_pairs` from each match's pair of light curves (`_pair_groups`)."""
    if len(group) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    peak = np.full(int(group.max()) + 1, -np.inf)
    np.fmax.at(peak, group, np.asarray(weaker, np.float64))
    return np.bincount(group)[group], peak[group]


def _pair_groups(chain1: NDArray[np.integer], chain2: NDArray[np.integer]) -> NDArray[np.intp]:
    curves = np.column_stack([chain1, chain2])
    return np.unique(curves, axis=0, return_inverse=True)[1].reshape(-1).astype(np.intp)
