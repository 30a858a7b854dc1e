"""The evidence on each flash candidate as numbers: what the evidence model weighs.

Every candidate of a camera gets one row of `FEATURES`, from its own camera and, once
the delay and the pose are known, from the other one:

* its own patch and spot: SNR, the classifier's probability, its peak foreground, the
  noise at the spot (peak over SNR: a sky seen through swaying leaves is noisier than
  the dark, and trees do not take the difference of two columns themselves), and how
  dark it is beside it: against the running background (`pipeline.blobs.trough`: a
  swaying edge is bright on one side, dark on the other) and against the frames a
  moment before (`pipeline.hollow`: a light that moved leaves a dark hollow where it
  was; a flash lights up from nothing);
* its light curve (`pipeline.acceptance.spot_chains`): how long the spot stays lit
  (faint peaks counted), how long it is a candidate, how many candidates the chain
  holds, the chain's best SNR and probability, and, explicit for the same reason as the
  noise, the candidate's SNR against that best and the share of the lit spell the
  candidates hold (in wind a flash's spot is busy: leaf clutter before and after it
  lengthens the spell and joins its chain);
* how crowded its camera is with candidates at least as strong (`as_strong_per_frame`):
  in a frame full of grain speckle a chance stereo partner is likely, in a quiet one not;
  and whether a stronger candidate of its frame lies a few pixels away
  (`brighter_neighbours`): the faint one of a crowded pair (`pipeline.crowding`) is a
  flash in a swarm, or the shoulder of a bright spot that is not round;
* the artifact tests: recurrence (`pipeline.recurrence`), flicker duty
  (`pipeline.flicker`), how many other light curves lit the same spot within seconds
  (`REVISIT_RADIUS_DEG`, `REVISIT_WINDOW_S`: a firefly moves between its flashes, a
  hole in the leaves lights one pixel again and again) and the step-1 verdict of the
  rules (`Verdict`, one-hot);
* stereo: whether the candidate is matched with a candidate of the other camera in the
  synchronised frame within the triangulation gates (`pipeline.triangulate`), that
  candidate's SNR, probability, light curve and verdict, the ray gap as an angle, and
  how long the two light curves are matched with each other.

Durations are in seconds, not frames, and angles in degrees, not pixels, so that a
model learnt at one frame rate and resolution reads the same evidence at another.
Features that would only describe the simulated scenes a model is trained on (the
elevation of a candidate, its range) are left out on purpose. Missing values (no match,
no recurrence measured) are NaN: the trees route them (`pipeline.trees`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from pipeline.acceptance import Evidence, Verdict, light_curve_pairs, steady_frames
from pipeline.detections import Detections
from pipeline.flicker import candidate_duty, spot_tree
from pipeline.geometry import Pose, pixel_to_bearing
from pipeline.params import FlickerParams, TriangulationParams
from pipeline.triangulate import triangulate

_VERDICTS = tuple(f"verdict_{v.name.lower()}" for v in Verdict)

_OWN: tuple[str, ...] = (
    "snr_log",
    "probability",
    "peak_log",
    "lit_s",
    "candidate_lit_s",
    "chain_candidates_s",
    "chain_peak_snr_log",
    "chain_peak_probability",
    "as_strong_per_frame_log",
    "recurrence",
    "flicker_duty",
    "spot_revisits",
    "noise_log",
    "chain_snr_share_log",
    "candidate_lit_share",
    "trough",
    "hollow",
    "brighter_neighbour_snr_share_log",
    "brighter_neighbour_px",
    *_VERDICTS,
)
#: Own columns of the matched candidate of the other camera, read as ``other_<name>``.
_PARTNER = ("snr_log", "probability", "lit_s", "verdict_confident")
_STEREO: tuple[str, ...] = (
    "stereo_matched",
    *(f"other_{name}" for name in _PARTNER),
    "other_plausible",
    "gap_deg",
    "pair_s",
    "pair_peak_snr_log",
)
#: Column names of a feature row, in order.
FEATURES: tuple[str, ...] = _OWN + _STEREO
#: Columns a second pass adds to a row: the first pass's flash probability relayed along
#: the candidate's links (`relayed_probabilities`).
RELAYED: tuple[str, ...] = (
    "partner_flash_probability",
    "light_curve_flash_probability",
    "pair_flash_probability",
    "confirmed_neighbour_flash_probability",
)
#: The `RELAYED` columns of second passes trained before the neighbours' was relayed.
FIRST_RELAYED: tuple[str, ...] = RELAYED[:3]

#: A firefly flashes again a few degrees from where it flashed, within seconds; light
#: curves nearer in time are the same flash, or its spot's clutter
#: (``confirmed_neighbour_flash_probability``; chosen out of fold on the tuning nights,
#: docs/detection.md).
NEIGHBOUR_RADIUS_DEG = 6.0
NEIGHBOUR_WINDOW_S = 3.0
NEIGHBOUR_MIN_GAP_S = 0.3
#: Light curves a first pass thinks less likely than this are not relayed as neighbours
#: (a windy night holds tens of thousands of clutter curves; none of them vouches).
NEIGHBOUR_MIN_PROBABILITY = 0.1


@dataclass(frozen=True)
class StereoMatches:
    """One-to-one matches between the two cameras' candidates.

    Attributes
    ----------
    index1, index2 : ndarray of intp
        Matched rows of camera 1's and camera 2's candidates.
    gap_deg : ndarray of float64
        Ray gap of each match as an angle at camera 1, degrees.
    """

    index1: NDArray[np.intp]
    index2: NDArray[np.intp]
    gap_deg: NDArray[np.float64]


def stereo_matches(
    candidates: tuple[Detections, Detections],
    delay_frames: int,
    pose: Pose,
    width: int,
    separation_m: float,
    gates: TriangulationParams,
) -> StereoMatches:
    """Match every candidate of one camera with the other's, frame by frame.

    Parameters
    ----------
    candidates : (Detections, Detections)
        All candidates of camera 1 and camera 2.
    delay_frames : int
        Camera-1 frame ``k`` is camera-2 frame ``k + delay_frames``.
    pose : Pose
        Camera 2 relative to camera 1.
    width : int
        Frame width in pixels.
    separation_m : float
        Camera separation, metres.
    gates : TriangulationParams
        The matching gates (`pipeline.triangulate.triangulate`).
    """
    points = triangulate(*candidates, delay_frames, pose, width, separation_m, gates)
    gap_deg = np.degrees(points.gap_m / np.maximum(points.range_m, 1e-9))
    return StereoMatches(
        points.index1.astype(np.intp), points.index2.astype(np.intp), gap_deg.astype(np.float64)
    )


@dataclass(frozen=True)
class CandidateLinks:
    """How the candidates of both cameras are linked, over their rows stacked (camera 1's,
    then camera 2's).

    Attributes
    ----------
    light_curve : ndarray of intp
        Light curve of each row (`pipeline.acceptance.spot_chains`), labels distinct
        across the cameras.
    partner : ndarray of intp
        Row of its stereo match in the other camera (`StereoMatches`), -1 if unmatched.
    sequence : ndarray of intp
        The recording each row was seen in (0 for camera 1, 1 for camera 2; nights
        stacked for training add 2 a night): rows of two sequences are never neighbours.
    time_s : ndarray of float64
        The row's frame in seconds from the start of its recording.
    bearing : ndarray of float64, shape (N, 3)
        The row's unit bearing in its camera's coordinates.
    """

    light_curve: NDArray[np.intp]
    partner: NDArray[np.intp]
    sequence: NDArray[np.intp]
    time_s: NDArray[np.float64]
    bearing: NDArray[np.float64]


def candidate_links(
    candidates: tuple[Detections, Detections],
    evidence: tuple[Evidence, Evidence],
    matches: StereoMatches,
    width: int,
    fps: float,
) -> CandidateLinks:
    """`CandidateLinks` of both cameras' candidates from their evidence and matches."""
    n1, n2 = len(evidence[0]), len(evidence[1])
    offset = int(evidence[0].chain.max()) + 1 if n1 else 0
    light_curve = np.concatenate([evidence[0].chain, evidence[1].chain + offset]).astype(np.intp)
    partner = np.full(n1 + n2, -1, dtype=np.intp)
    partner[matches.index1] = matches.index2 + n1
    partner[matches.index2 + n1] = matches.index1
    return CandidateLinks(
        light_curve,
        partner,
        sequence=np.repeat(np.arange(2, dtype=np.intp), [n1, n2]),
        time_s=np.concatenate([c.frame for c in candidates]).astype(np.float64) / fps,
        bearing=np.vstack([pixel_to_bearing(c.x, c.y, width) for c in candidates]).reshape(-1, 3),
    )


def relayed_probabilities(
    probability: NDArray[np.floating],
    links: CandidateLinks,
    columns: tuple[str, ...] = RELAYED,
) -> NDArray[np.float64]:
    """`RELAYED` columns: what a first pass thought of the candidates linked to each.

    A flash is one light curve in each camera, and the two are matched frame after
    frame; a first pass weighs each candidate apart, so the frames where a flash rises
    or falls, or where leaves crowd its spot, can look worse than its best frame, and
    than its match in the other camera. Per row (NaN where there is nothing to relay):

    * ``partner_flash_probability``: the stereo match's first-pass probability;
    * ``light_curve_flash_probability``: the largest one along its own light curve;
    * ``pair_flash_probability``: the largest ``light_curve_flash_probability`` of the
      other camera's light curves its light curve is matched with;
    * ``confirmed_neighbour_flash_probability``: the largest of the same camera's other
      light curves that a firefly could have flashed before or after it
      (`neighbour_probabilities`), each counting the smaller of its
      ``light_curve_flash_probability`` and its ``pair_flash_probability``: what both
      cameras made of it.

    Parameters
    ----------
    probability : ndarray, shape (N,)
        First-pass flash probability of each row (camera 1's rows, then camera 2's).
    links : CandidateLinks
        Light curves, stereo partners, times and bearings of the same rows.
    columns : tuple of str
        The `RELAYED` columns wanted, in order (a model reads those it was trained on).

    Returns
    -------
    ndarray, shape (N, len(columns))
    """
    p = np.asarray(probability, np.float64)
    curve = links.light_curve
    n_curves = int(curve.max()) + 1 if len(curve) else 0
    curve_best = np.zeros(n_curves)
    np.maximum.at(curve_best, curve, p)
    matched = links.partner >= 0
    partner = links.partner[matched]
    out = np.full((len(p), len(RELAYED)), np.nan)
    out[matched, 0] = p[partner]
    out[:, 1] = curve_best[curve]
    pair_best = np.full(n_curves, np.nan)
    np.fmax.at(pair_best, curve[matched], curve_best[curve[partner]])
    out[:, 2] = pair_best[curve]
    if "confirmed_neighbour_flash_probability" in columns:  # a tree search: only when read
        # A neighbour vouches as far as the other camera saw it too: clutter in one
        # camera (moon through leaves) forms clusters that would vouch for each other.
        confirmed = np.fmin(curve_best, np.nan_to_num(pair_best, nan=0.0))
        out[:, 3] = neighbour_probabilities(p, confirmed, links)[curve]
    return out[:, [RELAYED.index(name) for name in columns]]


def neighbour_probabilities(
    probability: NDArray[np.float64], vouch: NDArray[np.float64], links: CandidateLinks
) -> NDArray[np.float64]:
    """Per light curve, the best probability of the same recording's light curves that
    could be the same firefly's flashes before or after it.

    A flash in front of swaying leaves looks like their clutter, but the firefly that
    made it flashes again every few seconds, a few degrees away, often where nothing
    hides it. Each light curve is placed at its most probable row; two are neighbours
    when those rows lie within `NEIGHBOUR_RADIUS_DEG` of each other and
    `NEIGHBOUR_MIN_GAP_S` to `NEIGHBOUR_WINDOW_S` apart in time. Only curves that vouch
    at least `NEIGHBOUR_MIN_PROBABILITY` are relayed.

    Parameters
    ----------
    probability : ndarray, shape (N,)
        First-pass flash probability of each row.
    vouch : ndarray, shape (C,)
        What each light curve relays to its neighbours (labels of ``links.light_curve``),
        e.g. its largest probability.
    links : CandidateLinks
        The rows' light curves, recordings, times and bearings.

    Returns
    -------
    ndarray, shape (C,)
        NaN where no neighbour is relayed.
    """
    curve = links.light_curve
    out = np.full(len(vouch), np.nan)
    order = np.lexsort((probability, curve))
    best_row = order[np.r_[curve[order][1:] != curve[order][:-1], True]] if len(curve) else order
    relayed = vouch[curve[best_row]] >= NEIGHBOUR_MIN_PROBABILITY
    if not relayed.any():
        return out
    # Chebyshev boxes of unit half-width: the radius's chord on each axis of the bearing,
    # the window in time; recordings 10 apart never meet. Exact distances below.
    chord = 2.0 * np.sin(np.radians(NEIGHBOUR_RADIUS_DEG) / 2.0)
    place = np.column_stack(
        [
            links.bearing[best_row] / chord,
            10.0 * links.sequence[best_row],
            links.time_s[best_row] / NEIGHBOUR_WINDOW_S,
        ]
    )
    pairs = cKDTree(place).sparse_distance_matrix(
        cKDTree(place[relayed]), 1.0, p=np.inf, output_type="ndarray"
    )
    to, src = best_row[pairs["i"]], best_row[np.flatnonzero(relayed)[pairs["j"]]]
    apart = np.abs(links.time_s[to] - links.time_s[src])
    near = np.linalg.norm(links.bearing[to] - links.bearing[src], axis=1) <= chord
    keep = near & (apart >= NEIGHBOUR_MIN_GAP_S) & (curve[to] != curve[src])
    np.fmax.at(out, curve[to[keep]], vouch[curve[src[keep]]])
    return out


def candidate_features(
    candidates: tuple[Detections, Detections],
    evidence: tuple[Evidence, Evidence],
    matches: StereoMatches,
    width: int,
    fps: float,
    flicker: FlickerParams,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The `FEATURES` of every candidate of camera 1 and of camera 2.

    Parameters
    ----------
    candidates, evidence : pairs (camera 1, camera 2)
        Every candidate of each camera and its step-1 evidence (`pipeline.acceptance`).
    matches : StereoMatches
        Stereo matches between the two cameras' candidates (`stereo_matches`).
    width : int
        Frame width in pixels.
    fps : float
        Frames per second.
    flicker : FlickerParams
        Neighbourhood and window of the flicker duty.

    Returns
    -------
    (ndarray, ndarray)
        Shapes (N1, len(FEATURES)) and (N2, len(FEATURES)).
    """
    pair_length, pair_peak = light_curve_pairs(
        evidence[0].chain[matches.index1],
        evidence[1].chain[matches.index2],
        np.fmin(candidates[0].snr[matches.index1], candidates[1].snr[matches.index2]),
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        pair = np.column_stack([pair_length / fps, np.log(pair_peak)])
    own = [
        _own_features(c, e, width, fps, flicker) for c, e in zip(candidates, evidence, strict=True)
    ]
    rows = []
    for camera, (mine, theirs) in enumerate(
        ((matches.index1, matches.index2), (matches.index2, matches.index1))
    ):
        partner = own[1 - camera]
        stereo = _stereo_features(len(own[camera]), mine, partner[theirs], matches.gap_deg, pair)
        rows.append(np.column_stack([own[camera], stereo]))
    return rows[0], rows[1]


def _own_features(
    det: Detections, ev: Evidence, width: int, fps: float, flicker: FlickerParams
) -> NDArray[np.float64]:
    n = len(det)
    if n == 0:
        return np.zeros((0, len(_OWN)))
    snr = det.snr.astype(np.float64)
    probability = det.flash_probability.astype(np.float64)
    candidate_lit = steady_frames(det.frame, ev.chain)
    chain_size = np.bincount(ev.chain)
    peak_snr = np.full(len(chain_size), -np.inf)
    np.fmax.at(peak_snr, ev.chain, snr)
    peak_probability = np.full(len(chain_size), -np.inf)
    np.fmax.at(peak_probability, ev.chain, probability)
    duty = ev.flicker_duty
    if duty is None:  # not measured by the merge stage
        duty = candidate_duty(det, width, fps, flicker)
    verdicts = np.eye(len(Verdict))[ev.verdict]
    revisits = _spot_revisits(det, ev.chain, width, fps)
    with np.errstate(divide="ignore", invalid="ignore"):
        snr_log = np.log(snr)
        peak_log = np.log(np.maximum(det.peak.astype(np.float64), 0.1))
        return np.column_stack(
            [
                snr_log,
                probability,
                peak_log,
                ev.lit_frames / fps,
                candidate_lit / fps,
                chain_size[ev.chain] / fps,
                np.log(peak_snr[ev.chain]),
                peak_probability[ev.chain],
                np.log(as_strong_per_frame(det.frame, snr, fps)),
                det.recurrence.astype(np.float64),
                duty,
                revisits[ev.chain],
                peak_log - snr_log,
                snr_log - np.log(peak_snr[ev.chain]),
                candidate_lit / ev.lit_frames,
                det.trough.astype(np.float64),
                det.hollow.astype(np.float64),
                *brighter_neighbours(det, width),
                verdicts,
            ]
        )


#: A candidate looks for a stronger one of its frame within this many pixels (Chebyshev):
#: a few point spreads. Pixels, not degrees: the spread of a spot is the sensor's.
BRIGHTER_NEIGHBOUR_PX = 6.0


def brighter_neighbours(
    det: Detections, width: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The nearest stronger candidate of the same frame, for each candidate.

    Parameters
    ----------
    det : Detections
        One camera's candidates.
    width : int
        Frame width in pixels (``x`` is periodic: the 360° seam).

    Returns
    -------
    share_log, distance_px : ndarray of float64, shape (N,)
        Log of the candidate's SNR over that of the nearest candidate of its frame with a
        larger SNR within `BRIGHTER_NEIGHBOUR_PX`, and the distance between the two in
        pixels; NaN where there is none.
    """
    n = len(det)
    share = np.full(n, np.nan)
    distance = np.full(n, np.nan)
    if n < 2:
        return share, distance
    # Frames 2 apart never meet in the unit Chebyshev ball.
    tree = spot_tree(2.0 * det.frame, det.x, det.y, width, BRIGHTER_NEIGHBOUR_PX * 360.0 / width)
    pairs = tree.query_pairs(1.0, p=np.inf, output_type="ndarray")
    if len(pairs) == 0:
        return share, distance
    snr = det.snr.astype(np.float64)
    a, b = pairs.T
    weak = np.where(snr[a] < snr[b], a, b)
    strong = a + b - weak
    keep = snr[strong] > snr[weak]  # a tie has no stronger one
    weak, strong = weak[keep], strong[keep]
    dx = (det.x[strong] - det.x[weak] + width / 2) % width - width / 2
    gap = np.hypot(dx, det.y[strong] - det.y[weak])
    order = np.lexsort((gap, weak))
    first = order[np.r_[True, weak[order][1:] != weak[order][:-1]]]
    share[weak[first]] = np.log(snr[weak[first]] / snr[strong[first]])
    distance[weak[first]] = gap[first]
    return share, distance


#: Length of the blocks of a recording over which `as_strong_per_frame` counts, seconds:
#: long enough to count the rare strong candidates, short enough to follow a night
#: that grows noisier.
CROWD_BLOCK_S = 10.0


def as_strong_per_frame(
    frame: NDArray[np.integer], snr: NDArray[np.floating], fps: float
) -> NDArray[np.float64]:
    """How many candidates of the camera are at least as strong, per frame.

    Parameters
    ----------
    frame : ndarray of int, shape (N,)
        Each candidate's frame index.
    snr : ndarray of float, shape (N,)
        Each candidate's peak SNR (matched filter over the noise σ).
    fps : float
        Frames per second.

    Returns
    -------
    ndarray of float64, shape (N,)
        The candidates of the same `CROWD_BLOCK_S` block of frames (counted from frame 0)
        whose SNR is at least the candidate's, itself included, divided by the frames of
        the block up to its last candidate: the expected number of candidates as strong
        in any one frame, which is what a chance stereo partner is drawn from.
    """
    n = len(frame)
    if n == 0:
        return np.zeros(0)
    length = max(1, round(CROWD_BLOCK_S * fps))
    frame = np.asarray(frame, np.int64)
    block = frame // length
    snr = np.asarray(snr, np.float64)
    order = np.lexsort((snr, block))  # by block, then ascending SNR
    b, v = block[order], snr[order]
    starts_tie = np.r_[True, (b[1:] != b[:-1]) | (v[1:] != v[:-1])]
    first_of_tie = np.maximum.accumulate(np.where(starts_tie, np.arange(n), 0))
    block_ids, block_end = np.unique(b, return_index=True)
    block_end = np.r_[block_end[1:], n]  # one past each block's last candidate
    slot = np.searchsorted(block_ids, b)
    last_frame = np.zeros(len(block_ids), np.int64)
    np.maximum.at(last_frame, slot, frame[order])
    frames = last_frame - block_ids * length + 1
    out = np.empty(n)
    out[order] = (block_end[slot] - first_of_tie) / frames[slot]
    return out


#: A light curve revisits its spot when another one lies this close (degrees) within
#: `REVISIT_WINDOW_S` on either side: a firefly moves between its flashes, a glint or a
#: hole in the leaves lights the same spot again and again.
REVISIT_RADIUS_DEG = 0.5
REVISIT_WINDOW_S = 10.0


def _spot_revisits(
    det: Detections, chain: NDArray[np.intp], width: int, fps: float
) -> NDArray[np.float64]:
    """Per chain: how many other chains lit the same spot (their mean positions within
    `REVISIT_RADIUS_DEG`, their mean frames within `REVISIT_WINDOW_S`)."""
    n_chains = int(chain.max()) + 1
    first = np.full(n_chains, len(chain))
    np.minimum.at(first, chain, np.arange(len(chain)))
    dx = (det.x - det.x[first[chain]] + width / 2) % width - width / 2
    size = np.bincount(chain, minlength=n_chains)
    x = (det.x[first] + np.bincount(chain, dx, n_chains) / size) % width
    y = np.bincount(chain, det.y, n_chains) / size
    t = np.bincount(chain, det.frame.astype(np.float64), n_chains) / size
    tree = spot_tree(t / (REVISIT_WINDOW_S * fps), x, y, width, REVISIT_RADIUS_DEG)
    counts = tree.query_ball_point(tree.data, r=1.0, p=np.inf, return_length=True)
    return np.asarray(counts, np.float64) - 1.0


def _stereo_features(
    n: int,
    mine: NDArray[np.intp],
    partner: NDArray[np.float64],
    gap_deg: NDArray[np.float64],
    pair: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Stereo columns of one camera's `n` candidates, of which rows `mine` are matched
    with candidates whose own feature rows are `partner` (`pair`: each match's light-curve
    pair length in seconds and log best weaker SNR); NaN where a candidate is unmatched
    (``stereo_matched`` 0)."""
    out = np.full((n, len(_STEREO)), np.nan)
    out[:, 0] = 0.0
    if len(mine) == 0:
        return out
    columns = [_OWN.index(name) for name in _PARTNER]
    plausible = (
        partner[:, _OWN.index("verdict_confident")] + partner[:, _OWN.index("verdict_doubtful")]
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        out[mine] = np.column_stack(
            [
                np.ones(len(mine)),
                partner[:, columns],
                plausible,
                gap_deg,
                pair,
            ]
        )
    return out
