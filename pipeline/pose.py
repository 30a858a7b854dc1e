"""Spatial calibration: the relative pose of camera 2 from single-flash frames.

In a synchronised frame where each camera sees exactly one flash, or sees exactly one
flash begin, the two bearings usually belong to the same firefly, so their rays must
meet. The pose (unit translation ``t̂`` and rotation ``R``, see `pipeline.geometry`) is
found by robust non-linear least squares on how far the rays miss each other:

* the optimal depths of every pair come in closed form from
  `pipeline.geometry.closest_approach` (one vectorised call per evaluation);
* the residual is the **depth-normalised gap** ``gap / sqrt(r1² + r2² + 1)`` (unit
  baseline). The raw gap grows with depth (a 0.1° bearing error misses by 1.7 cm at
  10 m but 1.7 mm at 1 m), so it would let far flashes dominate; ``gap / sqrt(r1² +
  r2²)`` is, to first order, the smallest root-sum-square rotation (radians) of the
  two bearings that makes the rays meet, i.e. an angular error comparable across
  depths. The ``+ 1`` (one baseline squared) keeps it finite for near-parallel rays.
* free depths make the objective smooth but blind to which side of the cameras the
  point lies: ``(R, t̂)``, ``(R, −t̂)`` and their "twisted" versions (``R`` composed
  with a half turn about ``t̂``) fit equally well. Cheirality (``r1, r2 > 0``) picks the
  one that puts the inliers in front of both cameras;
* starts: ``R = I`` with ``t̂`` along ``x`` and ``y`` (side-by-side set-ups; the sign is
  decided by cheirality, so ``±`` are the same start) and the essential-matrix
  solution of the linear 8-point algorithm on bearings;
* outliers (two different fireflies) are handled by a Cauchy loss at
  ``min_threshold_deg``, reached from each start both straight and with a scale
  shrinking from 10° (graduated non-convexity, which widens the starts' basins but lets
  a sixth of mismatched pairs pull a near start away), then an explicit, noise-adaptive
  inlier threshold and a plain least-squares refit on the inliers. The loss grows only
  logarithmically, so a few pairs 10° off cannot outweigh many that fit to 0.05°: a
  soft-L1 loss (growing as the residual) preferred a pose 10° off on a simulated 4K wind
  night whose 66 pairs held 5 such outliers. On synthetic pairs this holds up to about
  50 % mismatched pairs; beyond that the pose is unreliable (and a warning says so).

``R`` is parameterised by a rotation vector applied to the start rotation and ``t̂`` by
a 2-vector in the plane orthogonal to the start translation, so neither has a
singularity near the start.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from pipeline.acceptance import spot_chains
from pipeline.detections import Detections
from pipeline.geometry import Pose, RayPair, check_width, closest_approach, pixel_to_bearing
from pipeline.params import PoseParams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

_MAD_TO_SIGMA = 1.4826
#: Loss scales (degrees) of the graduated fit from each start, before the final scale.
_GRADUATED_SCALES_DEG = (10.0, 3.0, 1.0)
#: Evaluation budget of each graduated step: a start in the wrong basin stops early.
_START_NFEV = 100
#: `scipy.optimize.least_squares` loss of the starts and the first fit on all pairs.
_ROBUST_LOSS = "cauchy"
#: Central-difference step of `pose_covariance` (radians, ~0.0006°): small
#: against good fits' residuals (~0.03°) so the gaps' kink at zero barely matters.
_JACOBIAN_STEP_RAD = 1e-5


class PoseError(ValueError):
    """The pose cannot be estimated (too few calibration pairs or inliers)."""


@dataclass(frozen=True)
class CalibrationPairs:
    """Bearings of frames where each camera sees exactly one flash (or one begin).

    Attributes
    ----------
    frame1 : ndarray of int64, shape (N,)
        Camera-1 frame of each pair (camera 2's is ``frame1 + delay_frames``).
    bearing1, bearing2 : ndarray of float64, shape (N, 3)
        Unit bearings in camera 1 and camera 2 coordinates.
    """

    frame1: IntArray
    bearing1: FloatArray
    bearing2: FloatArray

    def __len__(self) -> int:
        return len(self.frame1)


@dataclass(frozen=True)
class PoseEstimate:
    """Result of `estimate_pose`.

    Attributes
    ----------
    pose : Pose
        Relative pose of camera 2 (``t̂`` unit, the sign chosen by cheirality).
    inliers : ndarray of bool, shape (N,)
        Pairs consistent with the pose: residual under the threshold and in front of
        both cameras.
    residuals : ndarray of float64, shape (N,)
        Depth-normalised ray gap of every pair, in degrees (≈ the angular error).
    gaps : ndarray of float64, shape (N,)
        Raw ray gap of every pair, in units of the camera separation.
    n_pairs, n_inliers : int
        Number of calibration pairs and of inliers.
    threshold_deg : float
        Inlier threshold used, in degrees.
    stats : dict
        ``median / mean / p90`` of the inliers' residuals, as ``*_deg`` (degrees) and
        ``*_gap`` (separation units), and the standard errors of the rotation and of
        the baseline's direction, ``rotation_se_deg`` and ``translation_se_deg``
        (`standard_errors_deg`).
    covariance : ndarray of float64, shape (6, 6)
        Of the rotation vector and the unit translation (`pose_covariance`).
    warnings : tuple of str
        Reasons to distrust the pose (few or a low fraction of inliers).
    """

    pose: Pose
    inliers: BoolArray
    residuals: FloatArray
    gaps: FloatArray
    n_pairs: int
    n_inliers: int
    threshold_deg: float
    stats: dict[str, float]
    covariance: FloatArray
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (without the per-pair arrays)."""
        return {
            **self.pose.to_dict(),
            "n_pairs": self.n_pairs,
            "n_inliers": self.n_inliers,
            "threshold_deg": self.threshold_deg,
            "residual_stats": self.stats,
            "warnings": list(self.warnings),
        }


def calibration_pairs(
    det1: Detections,
    det2: Detections,
    delay_frames: int,
    width: int,
    onset_radius_deg: float | None = None,
) -> CalibrationPairs:
    """Bearings of the synchronised frames where each camera sees exactly one flash, or
    exactly one flash begin.

    A frame where one flash begins in each camera pairs the two beginnings even when
    other flashes are lit: in a dense swarm frames with a single flash grow rare (80
    fireflies in view leave about one such frame a second) while single beginnings
    stay common.

    Parameters
    ----------
    det1, det2 : Detections
        Accepted flashes of camera 1 and camera 2 (pixels, ``x = u``, ``y = v``).
    delay_frames : int
        ``dk``: camera-1 frame ``k`` is camera-2 frame ``k + dk``.
    width : int
        Frame width in pixels (equirectangular, height ``width / 2``).
    onset_radius_deg : float or None
        A flash begins where no flash of the previous frame lies within this angle
        (`pipeline.acceptance.spot_chains`); None: single-flash frames only.

    Returns
    -------
    CalibrationPairs
        Sorted by camera-1 frame.
    """
    check_width(width)
    frame2 = det2.frame - int(delay_frames)
    rows1, rows2, frames = _paired_rows(*_single_rows(det1.frame), *_single_rows(frame2))
    if onset_radius_deg is not None:
        rows_b1, frames_b1 = _onset_rows(det1, width, onset_radius_deg)
        rows_b2, frames_b2 = _onset_rows(det2, width, onset_radius_deg)
        o1, o2, onset_frames = _paired_rows(
            rows_b1, frames_b1, rows_b2, frames_b2 - int(delay_frames)
        )
        new = ~np.isin(onset_frames, frames)
        order = np.argsort(np.r_[frames, onset_frames[new]], kind="stable")
        rows1 = np.r_[rows1, o1[new]][order]
        rows2 = np.r_[rows2, o2[new]][order]
        frames = np.r_[frames, onset_frames[new]][order]
    return CalibrationPairs(
        frame1=frames.astype(np.int64),
        bearing1=pixel_to_bearing(det1.x[rows1], det1.y[rows1], width),
        bearing2=pixel_to_bearing(det2.x[rows2], det2.y[rows2], width),
    )


def _paired_rows(
    rows1: IntArray, frames1: IntArray, rows2: IntArray, frames2: IntArray
) -> tuple[IntArray, IntArray, IntArray]:
    """Rows of both cameras at the frames both have one (frames unique, sorted)."""
    common, i1, i2 = np.intersect1d(frames1, frames2, assume_unique=True, return_indices=True)
    return rows1[i1], rows2[i2], common


def _onset_rows(det: Detections, width: int, radius_deg: float) -> tuple[IntArray, IntArray]:
    """Rows and frames of the frames where exactly one flash begins."""
    frame = det.frame
    chain = spot_chains(frame, det.x, det.y, width, radius_deg)
    if len(chain) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    first = np.full(chain.max() + 1, np.iinfo(np.int64).max)
    np.minimum.at(first, chain, frame)
    begins = np.flatnonzero(frame == first[chain])
    rows, frames = _single_rows(frame[begins])
    return begins[rows], frames


def estimate_pose(
    pairs: CalibrationPairs,
    params: PoseParams = PoseParams(),  # noqa: B008 - frozen, immutable default
) -> PoseEstimate:
    """Relative pose of camera 2 from calibration pairs, robust to mismatched pairs.

    Parameters
    ----------
    pairs : CalibrationPairs
        Bearings of single-flash frames (`calibration_pairs`).
    params : PoseParams
        Inlier threshold, refits, minimum number of pairs.

    Returns
    -------
    PoseEstimate
        Pose with ``R`` (world → camera 2) and unit ``t̂`` (camera 1 → camera 2, world
        frame), per-pair residuals (degrees) and gaps (separation units), inlier mask.
        Deterministic.

    Raises
    ------
    PoseError
        If there are fewer than ``min_pairs`` pairs or inliers.
    """
    n = len(pairs)
    if n < params.min_pairs:
        raise PoseError(
            f"only {n} calibration pairs (frames where each camera sees exactly one confident "
            f"flash, or one begin); at least {params.min_pairs} are needed to estimate the "
            "pose. A longer recording gives more; so does a lower acceptance.confident_snr, at "
            "some risk of artifacts among them"
        )
    b1, b2 = pairs.bearing1, pairs.bearing2
    scale = np.radians(params.min_threshold_deg)
    # Starts compete on an evenly spread subsample; the winner is refined on all pairs.
    sample = np.unique(np.linspace(0, n - 1, min(n, params.max_start_pairs)).astype(np.int64))
    s1, s2 = b1[sample], b2[sample]
    starts = [
        Pose(np.eye(3), np.array([1.0, 0.0, 0.0])),
        Pose(np.eye(3), np.array([0.0, 1.0, 0.0])),
        essential_matrix_pose(s1, s2),
    ]
    fits = [_fit_from(s1, s2, start, scale) for start in starts]
    pose = _fit(b1, b2, min(fits, key=lambda fit: fit[1])[0], loss=_ROBUST_LOSS, scale=scale)[0]
    threshold = _threshold(normalised_gap(closest_approach(b1, b2, pose)), params)
    pose = _in_front(b1, b2, pose, threshold)
    inliers = _inlier_mask(closest_approach(b1, b2, pose), threshold)
    for _ in range(params.max_refits):
        _require_inliers(inliers, threshold, params)
        pose = _fit(b1[inliers], b2[inliers], pose, loss="linear", scale=scale)[0]
        rays = closest_approach(b1, b2, pose)
        threshold = _threshold(normalised_gap(rays), params)
        previous, inliers = inliers, _inlier_mask(rays, threshold)
        if np.array_equal(inliers, previous):
            break
    _require_inliers(inliers, threshold, params)
    return _summarise(b1, b2, pose, threshold, params)


def normalised_gap(rays: RayPair) -> FloatArray:
    """Depth-normalised ray gap ``gap / sqrt(r1² + r2² + 1)`` in radians (approx.).

    To first order the smallest root-sum-square rotation of the two bearings that
    makes the rays meet; depths and gap in units of the camera separation.
    """
    return rays.gap / np.sqrt(rays.r1**2 + rays.r2**2 + 1.0)


def essential_matrix_pose(bearing1: FloatArray, bearing2: FloatArray) -> Pose:
    """Pose from the linear 8-point algorithm on bearing vectors.

    The epipolar constraint of the pose convention is ``α1 · (t̂ × Rᵀ α2) = 0``, i.e.
    ``α1ᵀ E α2 = 0`` with ``E = [t̂]ₓ Rᵀ``. ``E`` is the least-squares null vector of the
    stacked constraints, decomposed by SVD; of its four decompositions the one with
    most pairs in front of both cameras is returned.

    Parameters
    ----------
    bearing1, bearing2 : ndarray, shape (N, 3), N >= 8
        Unit bearings in camera 1 and camera 2 coordinates.
    """
    constraints = (bearing1[:, :, None] * bearing2[:, None, :]).reshape(-1, 9)
    # Null vector of the N×9 system = eigenvector of its 9×9 normal matrix.
    e = np.linalg.eigh(constraints.T @ constraints)[1][:, 0].reshape(3, 3)
    u, _, vt = np.linalg.svd(e)
    u *= np.sign(np.linalg.det(u))
    vt *= np.sign(np.linalg.det(vt))
    w = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    # E = [t]x M with M = Rᵀ in {U W Vᵀ, U Wᵀ Vᵀ} and t = ±u₃.
    candidates = [Pose((u @ m @ vt).T, sign * u[:, 2]) for m in (w, w.T) for sign in (1.0, -1.0)]
    return max(candidates, key=lambda pose: _n_in_front(closest_approach(bearing1, bearing2, pose)))


def _fit_from(b1: FloatArray, b2: FloatArray, start: Pose, floor: float) -> tuple[Pose, float]:
    """Robust fit from ``start``, straight at ``floor`` (radians) and graduated from 10°.

    A wide scale first smooths away the local minima that outliers create around a
    distant start (graduated non-convexity), but it also weighs mismatched pairs nearly
    fully, and they can pull a near start into a wrong basin that the fit at ``floor``
    then keeps. Of the two ends, the one with the lower final cost is returned, with
    that cost.
    """
    scales = [s for s in np.radians(_GRADUATED_SCALES_DEG) if s > floor]
    graduated = start
    for scale in scales:
        graduated = _fit(b1, b2, graduated, loss=_ROBUST_LOSS, scale=scale, max_nfev=_START_NFEV)[0]
    ends = [
        _fit(b1, b2, pose, loss=_ROBUST_LOSS, scale=floor, max_nfev=_START_NFEV)
        for pose in ((start,) if graduated is start else (start, graduated))
    ]
    return min(ends, key=lambda end: end[1])


def _fit(
    b1: FloatArray,
    b2: FloatArray,
    start: Pose,
    *,
    loss: str,
    scale: float,
    max_nfev: int | None = None,
) -> tuple[Pose, float]:
    """Local least-squares fit of the pose from ``start``; returns the pose and its cost."""
    pose_of = _local_parameters(start)
    residuals = _gaps_near(b1, b2, pose_of)
    result = least_squares(residuals, np.zeros(5), loss=loss, f_scale=scale, max_nfev=max_nfev)
    return pose_of(result.x), float(result.cost)


def _local_parameters(start: Pose) -> Callable[[FloatArray], Pose]:
    """Poses near ``start`` as a function of 5 parameters: a rotation vector applied to its
    rotation, and a 2-vector in the plane orthogonal to its translation."""
    r0, t0 = start.rotation, start.translation
    basis = _translation_basis(t0)

    def pose_of(p: FloatArray) -> Pose:
        return Pose(Rotation.from_rotvec(p[:3]).as_matrix() @ r0, t0 + basis @ p[3:])

    return pose_of


def _translation_basis(translation: FloatArray) -> FloatArray:
    """Orthonormal basis (3 × 2) of the plane orthogonal to a unit translation: its two
    freedoms as a direction."""
    return np.asarray(np.linalg.svd(translation[None, :])[2][1:].T)


def _gaps_near(
    b1: FloatArray, b2: FloatArray, pose_of: Callable[[FloatArray], Pose]
) -> Callable[[FloatArray], FloatArray]:
    """The pairs' depth-normalised gaps as a function of the local pose parameters."""

    def gaps(p: FloatArray) -> FloatArray:
        return normalised_gap(closest_approach(b1, b2, pose_of(p)))

    return gaps


def pose_covariance(bearing1: FloatArray, bearing2: FloatArray, pose: Pose) -> FloatArray:
    """Covariance of a fitted pose, from the pairs it was fitted on.

    The covariance of the 5 local parameters (a rotation vector applied to the pose's
    rotation, and the translation's two freedoms as a direction) is ``s² (JᵀJ)⁻¹``, with
    ``J`` the Jacobian of the pairs' depth-normalised gaps (central differences) and
    ``s²`` their residual variance (``N − 5`` degrees of freedom). Pairs that leave the
    pose unconstrained (few, or all in nearly one plane through the baseline) give a
    large covariance however small their residuals: a pose can fit such pairs well and
    still be wrong.

    Parameters
    ----------
    bearing1, bearing2 : ndarray of float64, shape (N, 3)
        Unit bearings of the pairs the pose was fitted on (its inliers).
    pose : Pose
        The fitted pose.

    Returns
    -------
    ndarray of float64, shape (6, 6)
        Over ``(ω, t̂)``: the rotation vector ``ω`` (radians) of a small rotation applied
        before ``R`` (``R' = exp([ω]×) R``) and the unit translation ``t̂`` (world
        frame; no variance along itself). ``inf`` everywhere with 5 pairs or fewer.
    """
    n = len(bearing1)
    if n <= 5:
        return np.full((6, 6), np.inf)
    residuals = _gaps_near(bearing1, bearing2, _local_parameters(pose))
    steps = _JACOBIAN_STEP_RAD * np.eye(5)
    jacobian = np.column_stack(
        [(residuals(step) - residuals(-step)) / (2 * _JACOBIAN_STEP_RAD) for step in steps]
    )
    variance = float(np.sum(residuals(np.zeros(5)) ** 2)) / (n - 5)
    local = variance * np.linalg.pinv(jacobian.T @ jacobian)
    to_global = np.zeros((6, 5))
    to_global[:3, :3] = np.eye(3)
    to_global[3:, 3:] = _translation_basis(pose.translation)
    return np.asarray(to_global @ local @ to_global.T)


def standard_errors_deg(covariance: FloatArray) -> tuple[float, float]:
    """Standard errors of a pose (`pose_covariance`) about its worst-determined axes:
    of the rotation, and of the baseline's direction, in degrees."""
    rotation, translation = _worst_variances(covariance)
    return float(np.degrees(np.sqrt(rotation))), float(np.degrees(np.sqrt(translation)))


def _worst_variances(covariance: FloatArray) -> tuple[float, float]:
    """Largest variance (rad²) of the rotation's block and of the translation's; ``inf``
    for a covariance that is not finite (an undetermined pose)."""
    if not np.isfinite(covariance).all():
        return float("inf"), float("inf")
    rotation, translation = (
        max(float(np.linalg.eigvalsh(covariance[part, part]).max()), 0.0)
        for part in (slice(0, 3), slice(3, 6))
    )
    return rotation, translation


def worst_axis_covariance(covariance: FloatArray, translation: FloatArray) -> FloatArray:
    """A pose covariance (`pose_covariance`) with each part spread evenly at its worst
    axis: the rotation by its largest variance about every axis, the baseline's direction
    by its largest variance in every direction across it, no correlation between them.

    Fitted poses are off by more than their covariance says (their pairs' position errors
    have heavy tails; "Why wind poses are 0.1–0.7° off" in docs/detection.md), so the
    uncertainty a pose gives its 3D points takes the worst axis of each part, not its
    exact shape.

    Parameters
    ----------
    covariance : ndarray of float64, shape (6, 6)
        Over the rotation vector (radians) and the unit translation.
    translation : ndarray of float64, shape (3,)
        The pose's unit translation.

    Returns
    -------
    ndarray of float64, shape (6, 6)
        ``σ_R² I₃ ⊕ σ_t² (I₃ − t̂ t̂ᵀ)``; ``inf`` everywhere if `covariance` is not finite.
    """
    rotation, across = _worst_variances(covariance)
    if not np.isfinite(rotation):
        return np.full((6, 6), np.inf)
    spread = np.zeros((6, 6))
    spread[:3, :3] = rotation * np.eye(3)
    spread[3:, 3:] = across * (np.eye(3) - np.outer(translation, translation))
    return spread


def _threshold(residuals: FloatArray, params: PoseParams) -> float:
    """Inlier threshold (radians): ``inlier_sigmas`` robust sigmas, clipped to the bounds.

    The residuals are non-negative, so their median is that of ``|N(0, σ)|``: 0.674 σ.
    """
    sigma = _MAD_TO_SIGMA * float(np.median(residuals))
    low, high = np.radians([params.min_threshold_deg, params.max_threshold_deg])
    return float(np.clip(params.inlier_sigmas * sigma, low, high))


def _in_front(b1: FloatArray, b2: FloatArray, pose: Pose, threshold: float) -> Pose:
    """Of the four poses with the same free-depth gaps, the one with most inliers in front."""
    t = pose.translation
    half_turn = 2.0 * np.outer(t, t) - np.eye(3)  # rotation by π about t̂
    candidates = [
        Pose(rotation, sign * t)
        for rotation in (pose.rotation, pose.rotation @ half_turn)
        for sign in (1.0, -1.0)
    ]
    return max(
        candidates,
        key=lambda c: int(_inlier_mask(closest_approach(b1, b2, c), threshold).sum()),
    )


def _require_inliers(inliers: BoolArray, threshold: float, params: PoseParams) -> None:
    # Below a share of the pairs, the agreement is what unrelated pairs find by chance.
    needed = max(params.min_pairs, math.ceil(params.min_agreement * len(inliers)))
    if inliers.sum() < needed:
        raise PoseError(
            f"only {int(inliers.sum())} of {len(inliers)} calibration pairs agree on a pose "
            f"(threshold {np.degrees(threshold):.2f}°); at least {needed} needed"
        )


def _inlier_mask(rays: RayPair, threshold: float) -> BoolArray:
    return (normalised_gap(rays) < threshold) & (rays.r1 > 0) & (rays.r2 > 0)


def _n_in_front(rays: RayPair) -> int:
    return int(np.sum((rays.r1 > 0) & (rays.r2 > 0)))


def _summarise(
    b1: FloatArray, b2: FloatArray, pose: Pose, threshold: float, params: PoseParams
) -> PoseEstimate:
    rays = closest_approach(b1, b2, pose)
    residuals = np.degrees(normalised_gap(rays))
    inliers = _inlier_mask(rays, threshold)
    n, n_in = len(b1), int(inliers.sum())
    covariance = pose_covariance(b1[inliers], b2[inliers], pose)
    rotation_se, translation_se = standard_errors_deg(covariance)
    stats = {
        **_describe(residuals[inliers], "deg"),
        **_describe(rays.gap[inliers], "gap"),
        "rotation_se_deg": rotation_se,
        "translation_se_deg": translation_se,
        "rotation_jackknife_se_deg": rotation_jackknife_se_deg(b1[inliers], b2[inliers], pose),
    }
    warnings = []
    if n_in < params.min_inlier_fraction * n:
        warnings.append(
            f"only {n_in} of {n} calibration pairs ({n_in / n:.0%}) are pose inliers: "
            "check the delay and the flash classifier"
        )
    return PoseEstimate(
        pose=pose,
        inliers=inliers,
        residuals=residuals,
        gaps=rays.gap,
        n_pairs=n,
        n_inliers=n_in,
        threshold_deg=float(np.degrees(threshold)),
        stats=stats,
        covariance=covariance,
        warnings=tuple(warnings),
    )


#: Blocks of consecutive calibration pairs the jackknife leaves out in turn.
JACKKNIFE_BLOCKS = 8


def rotation_jackknife_se_deg(bearing1: FloatArray, bearing2: FloatArray, pose: Pose) -> float:
    """Block-jackknife standard error of the rotation, worst axis, in degrees.

    The pairs of one flash share its position errors (a spot on a swaying edge is
    misplaced the same way in every frame it is lit), so the Jacobian's standard error,
    which takes every pair as independent, can promise a tenth of a degree while the
    pose is a degree off. Leaving out each of `JACKKNIFE_BLOCKS` blocks of consecutive
    pairs in turn (pairs are in frame order, so a block holds whole flashes) and
    refitting from `pose` shows how far any one stretch of the night pulls it.

    Parameters
    ----------
    bearing1, bearing2 : ndarray of float64, shape (N, 3)
        Unit bearings of the inlier pairs, in frame order.
    pose : Pose
        The pose fitted on all of them (the start of each refit).

    Returns
    -------
    float
        ``sqrt((K − 1) / K · Σ (v_k − v̄)²)`` of the rotation vectors ``v_k`` of
        ``R_k Rᵀ``, the largest over the three axes, in degrees; NaN with fewer than
        three pairs a block.
    """
    n = len(bearing1)
    if n < 3 * JACKKNIFE_BLOCKS:
        return float("nan")
    vectors = []
    for block in np.array_split(np.arange(n), JACKKNIFE_BLOCKS):
        keep = np.ones(n, bool)
        keep[block] = False
        # Least squares like the final fit of `estimate_pose` (a linear loss has no scale).
        refit = _fit(bearing1[keep], bearing2[keep], pose, loss="linear", scale=1.0)[0]
        vectors.append(Rotation.from_matrix(refit.rotation @ pose.rotation.T).as_rotvec())
    v = np.array(vectors)
    k = len(v)
    spread = np.sqrt((k - 1) / k * np.sum((v - v.mean(axis=0)) ** 2, axis=0))
    return float(np.degrees(spread.max()))


def median_residual_px(estimate: PoseEstimate, width: int) -> float:
    """Median inlier residual in pixels of angle of a frame `width` pixels wide."""
    return estimate.stats.get("median_deg", 0.0) * width / 360.0


def rotation_se_deg(estimate: PoseEstimate) -> float:
    """The rotation's standard error in degrees: the larger of the Jacobian's and the
    block jackknife's (the jackknife sees errors that flashes share across their frames,
    the Jacobian a handful of pairs that cannot constrain an axis)."""
    return float(
        np.nanmax(
            [
                estimate.stats.get("rotation_se_deg", 0.0),
                estimate.stats.get("rotation_jackknife_se_deg", np.nan),
            ]
        )
    )


def jackknife_scale(estimate: PoseEstimate) -> float:
    """How many times the block jackknife's rotation standard error exceeds the
    Jacobian's: at least 1, and 1 where either is unknown (too few pairs to jackknife)."""
    jacobian = estimate.stats.get("rotation_se_deg", 0.0)
    jackknife = estimate.stats.get("rotation_jackknife_se_deg", math.nan)
    return float(jackknife / jacobian) if jacobian > 0 and jackknife > jacobian else 1.0


def translation_se_deg(estimate: PoseEstimate) -> float:
    """The baseline direction's standard error in degrees: the Jacobian's, scaled by
    `jackknife_scale` as the covariance the points' ranges take is
    (`pipeline.pose_refit.jackknife_scaled`)."""
    return float(estimate.stats.get("translation_se_deg", 0.0) * jackknife_scale(estimate))


def baseline_warnings(estimate: PoseEstimate, params: PoseParams) -> list[str]:
    """A warning when the baseline's direction is poorly determined (`translation_se_deg`
    above ``params.max_translation_se_deg``): a direction δ off moves a point's range by
    up to about δ in radians of itself (1° ≈ 1.7 %), whatever the rotation's precision.

    Not one of `fit_warnings`, which choose among refits: it reports the pose kept.
    """
    se = translation_se_deg(estimate)
    if se <= params.max_translation_se_deg:
        return []
    return [
        f"the baseline's direction is poorly determined (standard error {se:.2f}°, good "
        f"fits measure under {params.max_translation_se_deg:g}°) by its "
        f"{estimate.n_inliers} pairs: 3D ranges may be off by {np.radians(2 * se):.0%} "
        "or more; a longer recording, or flashes spread over more of the sky, would "
        "constrain it"
    ]


def fit_warnings(estimate: PoseEstimate, width: int, params: PoseParams) -> list[str]:
    """Warnings on how well the pose fits its inliers, in pixels of angle of a frame
    `width` pixels wide (a residual is only small or large against the pixel)."""
    warnings = []
    median_px = median_residual_px(estimate, width)
    if median_px > params.max_median_residual_px:
        warnings.append(
            f"the pose fits its calibration pairs poorly (median residual {median_px:.2f} px, "
            f"good fits measure about 0.1 px): the 3D results may be wrong; the confident "
            "flashes may include artifacts (try a higher acceptance.confident_snr or "
            "classifier.threshold)"
        )
    se = rotation_se_deg(estimate)
    if se > params.max_rotation_se_deg:
        warnings.append(
            f"the pose is poorly determined (rotation standard error {se:.2f}°, good fits "
            f"measure under 0.2°) by its {estimate.n_inliers} calibration pairs: the 3D "
            "results may be wrong; a longer recording, or flashes above and below the "
            "horizon, would constrain it"
        )
    return warnings


@dataclass(frozen=True)
class Calibrated:
    """Result of `calibrate_pose`.

    Attributes
    ----------
    estimate : PoseEstimate
        The pose kept.
    pairs : CalibrationPairs
        The calibration pairs it was fitted on.
    min_snr : float or None
        SNR floor of the flashes those pairs were made of; None: every flash given.
    warnings : list of str
        The estimate's warnings, `fit_warnings` and `baseline_warnings`.
    tried : list of dict
        Every fit tried, in order: ``min_snr``, ``n_pairs``, ``n_inliers``,
        ``median_residual_px`` (or ``error`` when no pose could be fitted).
    """

    estimate: PoseEstimate
    pairs: CalibrationPairs
    min_snr: float | None
    warnings: list[str]
    tried: list[dict[str, Any]]


def calibrate_pose(
    det1: Detections,
    det2: Detections,
    delay_frames: int,
    width: int,
    params: PoseParams = PoseParams(),  # noqa: B008 - frozen, immutable default
) -> Calibrated:
    """Relative pose from the given flashes; a doubtful fit is refitted from brighter ones.

    Artifacts that pass as flashes (glints through swaying leaves) pair with flashes of
    the other camera and can pull the fit into a wrong pose that fits its pairs poorly
    (`fit_warnings`) or keeps few inliers. Such a fit is refitted from the flashes at or
    above each SNR of ``params.refit_snr`` in turn: the first fit without warnings is
    kept, else the one with the fewest, then the smallest rotation standard error
    (`rotation_se_deg`), then the smallest median residual (its warnings kept). A fit
    that fails outright (too few pairs agree: on a grainy night speckle passes as
    confident flashes) is refitted from the brighter flashes in the same way.

    Parameters
    ----------
    det1, det2 : Detections
        Flashes of camera 1 and camera 2 (pixels; ``snr`` in units of the noise σ).
    delay_frames : int
        ``dk``: camera-1 frame ``k`` is camera-2 frame ``k + dk``.
    width : int
        Frame width in pixels.
    params : PoseParams
        Fit parameters, the warning levels and the refit SNR floors.

    Raises
    ------
    PoseError
        If no pose can be fitted from the flashes given, nor from the brighter ones
        alone (too few pairs or inliers).
    """
    best: Calibrated | None = None
    failed: PoseError | None = None
    tried: list[dict[str, Any]] = []
    for min_snr in (None, *params.refit_snr):
        sel1, sel2 = (d if min_snr is None else d.select(d.snr >= min_snr) for d in (det1, det2))
        pairs = calibration_pairs(sel1, sel2, delay_frames, width, params.onset_radius_deg)
        try:
            estimate = estimate_pose(pairs, params)
        except PoseError as error:
            tried.append({"min_snr": min_snr, "n_pairs": len(pairs), "error": str(error)})
            if best is not None:
                break  # a fit exists; brighter floors only hold fewer flashes
            # No fit yet: speckle as confident as flashes (a grainy night) can leave too
            # few pairs agreeing; the brighter flashes alone may still agree.
            failed = failed or error
            continue
        warnings = [*estimate.warnings, *fit_warnings(estimate, width, params)]
        residual = median_residual_px(estimate, width)
        tried.append(
            {
                "min_snr": min_snr,
                "n_pairs": estimate.n_pairs,
                "n_inliers": estimate.n_inliers,
                "median_residual_px": residual,
            }
        )
        fit = Calibrated(estimate, pairs, min_snr, warnings, tried)
        if not warnings:
            return _with_baseline_warnings(fit, params)
        if best is None or _doubt(fit, width) < _doubt(best, width):
            best = fit
    if best is None:
        assert failed is not None
        floors = ", ".join(f"{snr:g}" for snr in params.refit_snr)
        raise PoseError(
            f"{failed}; nor from the flashes of at least {floors} σ alone"
            if floors
            else str(failed)
        ) from None
    return _with_baseline_warnings(best, params)


def _with_baseline_warnings(fit: Calibrated, params: PoseParams) -> Calibrated:
    return replace(fit, warnings=[*fit.warnings, *baseline_warnings(fit.estimate, params)])


def _doubt(fit: Calibrated, width: int) -> tuple[int, float, float]:
    """Order of preference among fits with warnings: fewer warnings, then the smaller
    rotation standard error, then the smaller residual. Not the residual first: a fit of
    a dozen bright pairs fits them closely whatever the pose (held-out hard-all s305:
    13 inliers to 0.02 px, 71° off, against 39 inliers, 0.29° off)."""
    return len(fit.warnings), rotation_se_deg(fit.estimate), median_residual_px(fit.estimate, width)


def _describe(values: FloatArray, unit: str) -> dict[str, float]:
    return {
        f"median_{unit}": float(np.median(values)),
        f"mean_{unit}": float(np.mean(values)),
        f"p90_{unit}": float(np.percentile(values, 90)),
    }


def _single_rows(frames: IntArray) -> tuple[IntArray, IntArray]:
    """Rows and frames of the frames that hold exactly one entry."""
    unique, first, count = np.unique(frames, return_index=True, return_counts=True)
    single = count == 1
    return first[single], unique[single]
