"""Per-frame matching of flashes between the cameras and their triangulation.

In every synchronised frame pair (camera-1 frame ``k``, camera-2 frame ``k + dk``) each
camera-1 flash is matched to at most one camera-2 flash by minimum total ray gap
(Hungarian assignment), pairs whose rays miss by more than a gate are refused, and each
match is triangulated at the midpoint of the rays' closest approach.

All candidate pairs of all frames are built and scored in one vectorised pass; frames
with a single flash in either camera, or without competing candidates, are decided
without a solver, and `scipy.optimize.linear_sum_assignment` runs only on frames where
several flashes on both sides compete.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Self

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from pipeline.detections import Detections
from pipeline.geometry import Pose, check_width, closest_approach, pixel_to_bearing
from pipeline.params import TriangulationParams, validate_separation

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class Points3D:
    """Triangulated flashes, sorted by frame.

    Attributes
    ----------
    xyz : ndarray of float64, shape (N, 3)
        Positions in metres in camera 1's frame (``z`` up).
    frame : ndarray of int64
        Camera-1 frame.
    gap_m : ndarray of float64
        Ray gap of the match in metres (its triangulation error).
    range_m : ndarray of float64
        Distance from camera 1 in metres.
    index1, index2 : ndarray of int64
        Rows of the camera-1 and camera-2 detections that were matched.
    """

    xyz: FloatArray
    frame: IntArray
    gap_m: FloatArray
    range_m: FloatArray
    index1: IntArray
    index2: IntArray

    def __len__(self) -> int:
        return len(self.frame)

    def select(self, mask: NDArray[np.bool_] | IntArray) -> Self:
        """Rows picked by a boolean mask or an integer index array."""
        return type(self)(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})


def triangulate(
    det1: Detections,
    det2: Detections,
    delay_frames: int,
    pose: Pose,
    width: int,
    separation_m: float,
    params: TriangulationParams = TriangulationParams(),  # noqa: B008 - frozen default
) -> Points3D:
    """Match flashes between the cameras frame by frame and triangulate them.

    Parameters
    ----------
    det1, det2 : Detections
        Accepted flashes of camera 1 and camera 2 (pixels, ``x = u``, ``y = v``).
    delay_frames : int
        ``dk``: camera-1 frame ``k`` is camera-2 frame ``k + dk``.
    pose : Pose
        Pose of camera 2 relative to camera 1 (unit translation).
    width : int
        Frame width in pixels (equirectangular).
    separation_m : float
        Distance between the cameras in metres: the scale of the reconstruction.
    params : TriangulationParams
        Matching gates, maximum range and minimum parallax.

    Returns
    -------
    Points3D
        One point per accepted match, positions in metres in camera 1's frame. Matches
        with a gap of ``gate`` or more (or of more than ``max_gap_deg`` as an angle),
        behind a camera or farther than ``max_range_m`` are not made; points the
        baseline subtends under ``min_parallax_px`` are dropped; frames seen by one
        camera only yield nothing.

    Raises
    ------
    ValueError
        If the separation is not a finite distance in ``(0, 100]`` m or the width is
        not a positive even number.
    """
    validate_separation(separation_m)
    check_width(width)
    pairs = candidate_pairs(det1.frame, det2.frame - int(delay_frames))
    i1, i2 = pairs.index1, pairs.index2
    rays = closest_approach(
        pixel_to_bearing(det1.x[i1], det1.y[i1], width),
        pixel_to_bearing(det2.x[i2], det2.y[i2], width),
        pose,
        nonnegative=True,
    )
    range_m = np.linalg.norm(rays.midpoint, axis=-1) * separation_m
    gap_deg = np.degrees(rays.gap / np.maximum(np.maximum(rays.r1, rays.r2), 1e-12))
    # Impossible matches (behind a camera, out of range, inconsistent directions) must
    # not take a flash from a possible one, so they are excluded before the assignment.
    possible = (
        (rays.r1 > 0)
        & (rays.r2 > 0)
        & (range_m <= params.max_range_m)
        & (gap_deg <= params.max_gap_deg)
    )
    chosen = assign(pairs, np.where(possible, rays.gap, np.inf), params.gate)
    # Ill-conditioned points are dropped after the assignment: their match is right,
    # only their depth is not, so they must still keep the flash from other matches.
    parallax_px = np.degrees(parallax(rays.midpoint[chosen], pose)) * width / 360.0
    chosen = chosen[parallax_px >= params.min_parallax_px]
    return Points3D(
        xyz=rays.midpoint[chosen] * separation_m,
        frame=det1.frame[i1[chosen]],
        gap_m=rays.gap[chosen] * separation_m,
        range_m=range_m[chosen],
        index1=i1[chosen],
        index2=i2[chosen],
    )


def parallax(point: FloatArray, pose: Pose) -> FloatArray:
    """Angle (radians) the baseline subtends at each point.

    Parameters
    ----------
    point : ndarray, shape (..., 3)
        Points in camera 1's frame, in units of the camera separation.
    pose : Pose
        Relative pose; camera 2 sits at the unit translation ``t``.

    Returns
    -------
    ndarray, shape (...)
        Angle between the directions from the point to the two cameras, in [0, π].
    """
    to1 = np.asarray(point, dtype=np.float64)
    to2 = to1 - pose.translation
    cross = np.linalg.norm(np.cross(to1, to2), axis=-1)
    return np.arctan2(cross, np.sum(to1 * to2, axis=-1))


@dataclass(frozen=True)
class CandidatePairs:
    """All (camera-1 row, camera-2 row) pairs of the frames both cameras see.

    Pairs are grouped in blocks, one per frame in ascending order; a block holds the
    ``n1 × n2`` pairs of its frame, camera-1 row major.

    Attributes
    ----------
    index1, index2 : ndarray of int64
        Rows of the camera-1 and camera-2 detections of each pair.
    frame : ndarray of int64
        Camera-1 frame of each block.
    start : ndarray of int64
        Position of each block's first pair.
    n1, n2 : ndarray of int64
        Flashes of each block's frame in camera 1 and camera 2.
    """

    index1: IntArray
    index2: IntArray
    frame: IntArray
    start: IntArray
    n1: IntArray
    n2: IntArray


def candidate_pairs(frame1: IntArray, frame2: IntArray) -> CandidatePairs:
    """Every (camera-1 row, camera-2 row) pair that shares a frame, by index arithmetic.

    Parameters
    ----------
    frame1, frame2 : ndarray of int64
        Frame of each detection, both in camera-1 frame numbers.
    """
    order1 = np.argsort(frame1, kind="stable")
    order2 = np.argsort(frame2, kind="stable")
    f1, first1, count1 = np.unique(frame1[order1], return_index=True, return_counts=True)
    f2, first2, count2 = np.unique(frame2[order2], return_index=True, return_counts=True)
    frames, c1, c2 = np.intersect1d(f1, f2, assume_unique=True, return_indices=True)
    n1, n2 = count1[c1], count2[c2]
    size = n1 * n2
    start = np.cumsum(size) - size
    block = np.repeat(np.arange(len(size)), size)
    within = np.arange(size.sum()) - start[block]
    row = first1[c1][block] + within // n2[block]
    col = first2[c2][block] + within % n2[block]
    return CandidatePairs(
        index1=order1[row].astype(np.int64),
        index2=order2[col].astype(np.int64),
        frame=frames.astype(np.int64),
        start=start.astype(np.int64),
        n1=n1.astype(np.int64),
        n2=n2.astype(np.int64),
    )


def assign(pairs: CandidatePairs, cost: FloatArray, gate: float) -> IntArray:
    """One-to-one matching per frame minimising the total cost, under a gate.

    Three cases, the first two vectorised over all frames:

    * one flash in either camera: the cheapest pair;
    * several flashes in both, but no flash with two in-gate candidates: every in-gate
      pair (there is nothing to choose);
    * otherwise `linear_sum_assignment` on the frame, gated pairs made prohibitively
      expensive so that as many in-gate pairs as possible are kept.

    Parameters
    ----------
    pairs : CandidatePairs
        Candidate pairs, in blocks per frame.
    cost : ndarray of float64
        Cost of each pair (the ray gap, separation units).
    gate : float
        Pairs with ``cost >= gate`` are never matched.

    Returns
    -------
    ndarray of int64
        Positions of the chosen pairs, ascending.
    """
    block = np.repeat(np.arange(len(pairs.start)), pairs.n1 * pairs.n2)
    in_gate = cost < gate
    simple = (pairs.n1 == 1) | (pairs.n2 == 1)
    cheapest = np.lexsort((cost, block))[pairs.start[simple]]
    # A detection with several in-gate candidates makes its whole frame contested.
    contested_row = np.bincount(pairs.index1[in_gate], minlength=pairs.index1.max(initial=0) + 1)
    contested_col = np.bincount(pairs.index2[in_gate], minlength=pairs.index2.max(initial=0) + 1)
    clash = in_gate & ((contested_row[pairs.index1] > 1) | (contested_col[pairs.index2] > 1))
    contested = np.bincount(block[clash], minlength=len(pairs.start)) > 0
    direct = np.flatnonzero(in_gate & ~simple[block] & ~contested[block])
    chosen = [cheapest, direct]
    hard = ~simple & contested
    for start, n1, n2 in zip(pairs.start[hard], pairs.n1[hard], pairs.n2[hard], strict=True):
        matrix = cost[start : start + n1 * n2].reshape(n1, n2)
        rows, cols = linear_sum_assignment(np.where(matrix < gate, matrix, gate * (n1 * n2 + 1)))
        chosen.append(start + rows * n2 + cols)
    picked = np.sort(np.concatenate(chosen)).astype(np.int64)
    return picked[in_gate[picked]]
