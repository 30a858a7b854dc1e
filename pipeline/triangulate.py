"""Per-frame matching of flashes between the cameras and their triangulation.

In every synchronised frame pair (camera-1 frame ``k``, camera-2 frame ``k + dk``) each
camera-1 flash is matched to at most one camera-2 flash by minimum total ray gap
(Hungarian assignment), pairs whose rays miss by more than a gate are refused, and each
match is triangulated at the midpoint of the rays' closest approach.

All candidate pairs of a batch of frames are built and scored in one vectorised pass;
frames with a single flash in either camera, or without competing candidates, are
decided without a solver, and `scipy.optimize.linear_sum_assignment` runs only on frames
where several flashes on both sides compete. Batches hold whole frames and about
`MAX_PAIRS` pairs, so memory stays bounded when every candidate is matched (the
acceptance stage's stereo evidence): a grainy 4K night makes ~470 candidates a frame
per camera, 80 million pairs in 12 s, which in one pass took 19 GB.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Self

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from pipeline.detections import Detections
from pipeline.geometry import Pose, check_width, closest_approach, pixel_to_bearing
from pipeline.params import TriangulationParams, validate_separation

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: SNR assumed for detections that carry none (imported from another method).
UNKNOWN_SNR = 10.0
#: A point is sure of its range when ``range_sd_m`` is at most this share of ``range_m``
#: (the project's 2 % accuracy target).
SURE_RELATIVE_SD = 0.02
#: Candidate pairs scored at once (a few hundred bytes each while they are scored).
MAX_PAIRS = 1_000_000


def sure_of_range(range_sd_m: ArrayLike, range_m: ArrayLike) -> NDArray[np.bool_]:
    """Points whose range standard deviation is at most `SURE_RELATIVE_SD` of their
    range (False where it is unknown)."""
    return np.asarray(range_sd_m) <= SURE_RELATIVE_SD * np.asarray(range_m)


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
    range_sd_m : ndarray of float64
        Standard deviation of ``range_m`` in metres that the detections' position errors
        cause, to first order (`range_sd`); NaN where unknown.
    index1, index2 : ndarray of int64
        Rows of the camera-1 and camera-2 detections that were matched.
    """

    xyz: FloatArray
    frame: IntArray
    gap_m: FloatArray
    range_m: FloatArray
    range_sd_m: FloatArray
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
    pose_covariance: FloatArray | None = None,
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
        Matching gates, maximum range, minimum parallax and the detections'
        localisation error (``localisation_px``: ``σ = localisation_px / √SNR`` pixels;
        rows without an SNR count as `UNKNOWN_SNR`).
    pose_covariance : ndarray of float64, shape (6, 6), optional
        Of the pose's rotation vector and unit translation
        (`pipeline.pose.pose_covariance`): the pose's own error, scaled by
        ``params.pose_error_scale``, adds to the detections' in ``range_sd_m``.

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
    frame2 = det2.frame - int(delay_frames)
    parts = []
    for rows1, rows2 in frame_batches(det1.frame, frame2, MAX_PAIRS):
        points = _triangulate_batch(
            det1.select(rows1),
            det2.select(rows2),
            frame2[rows2],
            pose,
            width,
            separation_m,
            params,
            pose_covariance,
        )
        parts.append(replace(points, index1=rows1[points.index1], index2=rows2[points.index2]))
    return Points3D(
        **{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Points3D)}
    )


def frame_batches(
    frame1: IntArray, frame2: IntArray, max_pairs: int
) -> list[tuple[IntArray, IntArray]]:
    """Rows of each camera split into batches of whole frames: the frames whose pairs
    start within the same `max_pairs` of the running count, so a batch holds under
    `max_pairs` pairs plus those of its last frame.

    Parameters
    ----------
    frame1, frame2 : ndarray of int64
        Frame of each detection, both in camera-1 frame numbers.
    max_pairs : int
        Pairs (camera-1 rows × camera-2 rows of a shared frame) a batch may hold.

    Returns
    -------
    list of (ndarray, ndarray)
        Ascending rows of camera 1 and camera 2 of each batch, in frame order; one batch
        of every row when all pairs fit.
    """
    f1, n1 = np.unique(frame1, return_counts=True)
    f2, n2 = np.unique(frame2, return_counts=True)
    shared, i1, i2 = np.intersect1d(f1, f2, assume_unique=True, return_indices=True)
    size = n1[i1].astype(np.int64) * n2[i2]
    if size.sum() <= max_pairs:
        return [(np.arange(len(frame1)), np.arange(len(frame2)))]
    batch = (np.cumsum(size) - size) // max_pairs
    last = np.r_[np.flatnonzero(np.diff(batch)), len(batch) - 1]
    upper = np.r_[shared[last[:-1]], np.iinfo(np.int64).max]  # frames up to this one
    lower = np.r_[np.iinfo(np.int64).min, upper[:-1]]
    return [
        (
            np.flatnonzero((frame1 > lo) & (frame1 <= hi)),
            np.flatnonzero((frame2 > lo) & (frame2 <= hi)),
        )
        for lo, hi in zip(lower, upper, strict=True)
    ]


def _triangulate_batch(
    det1: Detections,
    det2: Detections,
    frame2: IntArray,
    pose: Pose,
    width: int,
    separation_m: float,
    params: TriangulationParams,
    pose_covariance: FloatArray | None,
) -> Points3D:
    """`triangulate` of detections whose camera-2 frames are `frame2` (camera-1 frame
    numbers)."""
    pairs = candidate_pairs(det1.frame, frame2)
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
    j1, j2 = i1[chosen], i2[chosen]
    sd = range_sd(
        pixel_to_bearing(det1.x[j1], det1.y[j1], width),
        pixel_to_bearing(det2.x[j2], det2.y[j2], width),
        pose,
        localisation_rad(det1.snr[j1], width, params.localisation_px),
        localisation_rad(det2.snr[j2], width, params.localisation_px),
        None if pose_covariance is None else pose_covariance * params.pose_error_scale**2,
    )
    return Points3D(
        xyz=rays.midpoint[chosen] * separation_m,
        frame=det1.frame[j1],
        gap_m=rays.gap[chosen] * separation_m,
        range_m=range_m[chosen],
        range_sd_m=sd * separation_m,
        index1=j1,
        index2=j2,
    )


def localisation_rad(snr: ArrayLike, width: int, localisation_px: float) -> FloatArray:
    """Position error (1 σ, radians) of detections at signal-to-noise ratio `snr`.

    ``σ = localisation_px / √SNR`` equatorial pixels of ``360° / width``; NaN SNR counts
    as `UNKNOWN_SNR`. The square root, not the ``1 / SNR`` of white noise, is what the
    refined positions show on simulated nights (0.25 px at 5 σ, 0.13 px at 20 σ,
    0.05 px at 100 σ at 640 px): grain, compression and the light-curve fit flatten it.
    """
    snr = np.nan_to_num(np.asarray(snr, dtype=np.float64), nan=UNKNOWN_SNR)
    return localisation_px / np.sqrt(np.maximum(snr, 1.0)) * (2.0 * np.pi / width)


def range_sd(
    bearing1: FloatArray,
    bearing2: FloatArray,
    pose: Pose,
    sd1: FloatArray,
    sd2: FloatArray,
    pose_covariance: FloatArray | None = None,
) -> FloatArray:
    """First-order standard deviation of a triangulated point's distance from camera 1.

    Each bearing is taken as off by an isotropic angular error of σ radians; the
    derivative of the distance of the rays' closest-approach midpoint along two
    directions orthogonal to each bearing (central differences) gives the variance
    ``Σ (∂r/∂θ)² σ²``. Far points, and points near the baseline's axis, are uncertain:
    ``σ_r ≈ r² √(σ1² + σ2²) / (B sin β)``. The pose's own error, when its covariance is
    given, adds ``gᵀ C g`` with ``g`` the derivative of the distance by the pose's six
    parameters: every point of a recording shares it, so it moves them together.

    Parameters
    ----------
    bearing1, bearing2 : ndarray, shape (N, 3)
        Unit bearings in camera 1 and camera 2 coordinates.
    pose : Pose
        Relative pose (unit translation).
    sd1, sd2 : ndarray, shape (N,)
        Angular errors (1 σ, radians) of the bearings.
    pose_covariance : ndarray, shape (6, 6), optional
        Of the rotation vector (radians, applied before ``R``) and the unit translation
        (`pipeline.pose.pose_covariance`); non-finite entries (an undetermined pose)
        make every deviation infinite.

    Returns
    -------
    ndarray, shape (N,)
        Standard deviation of the distance, in units of the camera separation.
    """

    def distance(b1: FloatArray, b2: FloatArray, at: Pose = pose) -> FloatArray:
        return np.linalg.norm(closest_approach(b1, b2, at).midpoint, axis=-1)

    step = 1e-6  # radians: central differences
    variance = np.zeros(len(bearing1))
    for camera, (bearing, sd) in enumerate(((bearing1, sd1), (bearing2, sd2))):
        for direction in _tangents(bearing):
            turned = [_unit(bearing + sign * step * direction) for sign in (1.0, -1.0)]
            pairs = [(t, bearing2) if camera == 0 else (bearing1, t) for t in turned]
            ahead, behind = (distance(*pair) for pair in pairs)
            variance += ((ahead - behind) / (2 * step) * sd) ** 2
    if pose_covariance is not None:
        if not np.isfinite(pose_covariance).all():
            return np.full(len(bearing1), np.inf)
        gradient = np.column_stack(
            [
                (
                    distance(bearing1, bearing2, _nudged(pose, i, step))
                    - distance(bearing1, bearing2, _nudged(pose, i, -step))
                )
                / (2 * step)
                for i in range(6)
            ]
        )
        variance += np.einsum("ni,ij,nj->n", gradient, pose_covariance, gradient)
    return np.sqrt(variance)


def _nudged(pose: Pose, parameter: int, step: float) -> Pose:
    """`pose` with one of its six parameters (`range_sd`) moved by `step`."""
    if parameter < 3:
        turn = Rotation.from_rotvec(step * np.eye(3)[parameter]).as_matrix()
        return Pose(turn @ pose.rotation, pose.translation)
    return Pose(pose.rotation, pose.translation + step * np.eye(3)[parameter - 3])


def _tangents(bearing: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit vectors orthogonal to each bearing and to each other."""
    # Any axis not parallel to the bearing: z, except near the poles.
    axis = np.where(np.abs(bearing[:, 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    first = _unit(np.cross(bearing, axis))
    return first, np.cross(bearing, first)


def _unit(v: FloatArray) -> FloatArray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


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
