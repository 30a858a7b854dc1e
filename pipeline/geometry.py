"""Equirectangular geometry, camera pose and two-ray triangulation.

Conventions (CONTRACT, see DESIGN.md)
-------------------------------------
* Frames are equirectangular with width ``W = 2 H``. A pixel position ``(u, v)``
  (``u`` column, ``v`` row, 0-based and continuous; the centre of pixel column ``i``
  is ``u = i``) maps to ``θ = 2π u / W`` and ``φ = π v / H`` and to the unit bearing
  ``α = (cos θ sin φ, sin θ sin φ, cos φ)``. ``z`` is up (row 0 is the zenith) and
  ``u`` wraps around at ``W``.
* Camera 1 is the world frame. Camera 2 sits at ``T = s t̂`` (``s`` the separation in
  metres, ``|t̂| = 1``) and is rotated by ``R``: a world point ``X`` is seen by camera 2
  along ``α2 = R (X − T) / |X − T|``, i.e. ``X = r1 α1 = T + Rᵀ r2 α2``.

All functions are vectorised over leading axes: bearings are ``(..., 3)`` arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def check_width(width: int) -> None:
    """Refuse a frame width that cannot be an equirectangular frame's.

    Raises
    ------
    ValueError
        If `width` is not a positive even number of pixels.
    """
    if int(width) != width or width <= 0 or width % 2:
        raise ValueError(f"width must be a positive even number of pixels, got {width!r}")


def pixel_to_bearing(u: ArrayLike, v: ArrayLike, width: int) -> FloatArray:
    """Unit bearing vectors of equirectangular pixel positions.

    Parameters
    ----------
    u, v : array_like
        Column and row positions in pixels (0-based, continuous; pixel centres at
        integers). ``u`` may lie outside ``[0, W)``: it wraps.
    width : int
        Frame width ``W`` in pixels; the height is ``W / 2``.

    Returns
    -------
    ndarray, shape ``broadcast(u, v).shape + (3,)``
        Unit vectors in the camera frame, ``z`` up.
    """
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    height = width / 2.0
    theta = 2.0 * np.pi * u / width
    phi = np.pi * v / height
    sin_phi = np.sin(phi)
    return np.stack(
        np.broadcast_arrays(np.cos(theta) * sin_phi, np.sin(theta) * sin_phi, np.cos(phi)),
        axis=-1,
    )


def bearing_to_pixel(bearing: ArrayLike, width: int) -> tuple[FloatArray, FloatArray]:
    """Equirectangular pixel positions of bearing vectors (inverse of `pixel_to_bearing`).

    Parameters
    ----------
    bearing : array_like, shape (..., 3)
        Direction vectors; need not be unit length.
    width : int
        Frame width ``W`` in pixels.

    Returns
    -------
    u : ndarray
        Column in ``[0, W)``.
    v : ndarray
        Row in ``[0, H]``.
    """
    b = np.asarray(bearing, dtype=np.float64)
    norm = np.linalg.norm(b, axis=-1)
    theta = np.mod(np.arctan2(b[..., 1], b[..., 0]), 2.0 * np.pi)
    phi = np.arccos(np.clip(b[..., 2] / norm, -1.0, 1.0))
    u = theta * width / (2.0 * np.pi)
    # mod can round 2π - ε up to exactly W; keep u in [0, W).
    u = np.where(u >= width, u - width, u)
    v = phi * (width / 2.0) / np.pi
    return u, v


def wrap_u(u: ArrayLike, width: int) -> FloatArray:
    """Wrap column positions into ``[0, W)``."""
    return np.mod(np.asarray(u, dtype=np.float64), width)


def angle_between(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Angle in radians between vectors ``a`` and ``b`` along the last axis (stable)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    dot = np.sum(a * b, axis=-1)
    return np.arctan2(cross, dot)


def rotation_angle(r_a: ArrayLike, r_b: ArrayLike) -> float:
    """Angle in radians of the rotation ``r_a r_bᵀ`` (0 when the rotations agree)."""
    m = np.asarray(r_a, dtype=np.float64) @ np.asarray(r_b, dtype=np.float64).T
    return float(np.arccos(np.clip((np.trace(m) - 1.0) / 2.0, -1.0, 1.0)))


@dataclass(frozen=True)
class Pose:
    """Pose of camera 2 relative to camera 1 (the world frame).

    Attributes
    ----------
    rotation : ndarray, shape (3, 3)
        ``R``: maps world directions to camera-2 directions.
    translation : ndarray, shape (3,)
        ``t̂``: unit direction from camera 1 to camera 2, in the world frame.
    """

    rotation: FloatArray = field(default_factory=lambda: np.eye(3))
    translation: FloatArray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))

    def __post_init__(self) -> None:
        r = np.asarray(self.rotation, dtype=np.float64).reshape(3, 3)
        t = np.asarray(self.translation, dtype=np.float64).reshape(3)
        norm = np.linalg.norm(t)
        if not np.isfinite(norm) or norm == 0:
            raise ValueError("Pose translation must be a non-zero finite vector")
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "translation", t / norm)

    def world_to_camera2(self, points: ArrayLike, separation: float = 1.0) -> FloatArray:
        """Camera-2 coordinates ``R (X − s t̂)`` of world points ``X`` (shape (..., 3))."""
        x = np.asarray(points, dtype=np.float64)
        return (x - separation * self.translation) @ self.rotation.T

    def camera2_directions_in_world(self, bearing2: ArrayLike) -> FloatArray:
        """World-frame directions ``Rᵀ α2`` of camera-2 bearings (shape (..., 3))."""
        return np.asarray(bearing2, dtype=np.float64) @ self.rotation

    def to_dict(self) -> dict[str, list]:
        return {"rotation": self.rotation.tolist(), "translation": self.translation.tolist()}


@dataclass(frozen=True)
class RayPair:
    """Closest approach of the rays ``r1 α1`` and ``T + r2 Rᵀ α2``.

    Attributes
    ----------
    r1, r2 : ndarray
        Depths along each ray, in units of the baseline length ``|T|``.
    gap : ndarray
        Distance between the two closest points, same units.
    midpoint : ndarray, shape (..., 3)
        Midpoint of the two closest points, in the world frame.
    """

    r1: FloatArray
    r2: FloatArray
    gap: FloatArray
    midpoint: FloatArray


def closest_approach(
    bearing1: ArrayLike,
    bearing2: ArrayLike,
    pose: Pose,
    *,
    nonnegative: bool = False,
) -> RayPair:
    """Closed-form closest approach of corresponding rays from the two cameras.

    Solves ``min |r1 a − (T + r2 b)|`` with ``a = α1``, ``b = Rᵀ α2`` and the unit
    baseline ``T = t̂`` for every pair at once, without an iterative solver.

    Parameters
    ----------
    bearing1, bearing2 : array_like, shape (..., 3)
        Unit bearings in camera 1 and camera 2 coordinates.
    pose : Pose
        Relative pose; the baseline is taken as unit length, so depths and gaps are
        in units of the camera separation.
    nonnegative : bool
        If true, constrain ``r1, r2 >= 0`` (points behind a camera are not allowed:
        the gap then measures how far the rays are from meeting in front of both).

    Returns
    -------
    RayPair
    """
    a = np.asarray(bearing1, dtype=np.float64)
    b = pose.camera2_directions_in_world(bearing2)
    t = pose.translation
    c = np.sum(a * b, axis=-1)
    at = a @ t
    bt = b @ t
    denom = 1.0 - c * c
    parallel = denom < 1e-12
    safe = np.where(parallel, 1.0, denom)
    r1 = np.where(parallel, at, (at - c * bt) / safe)
    r2 = np.where(parallel, 0.0, (c * at - bt) / safe)
    if nonnegative:
        r1, r2 = _clamp_depths(r1, r2, at, bt)
    p1 = r1[..., None] * a
    p2 = t + r2[..., None] * b
    gap = np.linalg.norm(p1 - p2, axis=-1)
    return RayPair(r1=r1, r2=r2, gap=gap, midpoint=0.5 * (p1 + p2))


def _clamp_depths(
    r1: FloatArray, r2: FloatArray, at: FloatArray, bt: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Minimiser of the ray gap on the quadrant ``r1, r2 >= 0``.

    The objective is convex, so if the free minimum is infeasible the constrained one
    lies on an edge: ``r1 = 0`` (best ``r2 = max(0, −b·t)``) or ``r2 = 0`` (best
    ``r1 = max(0, a·t)``); take whichever edge point is closer.
    """
    feasible = (r1 >= 0) & (r2 >= 0)
    # Edge r2 = 0: |r1 a − t|² = r1² − 2 r1 a·t + 1.
    e1_r1 = np.maximum(at, 0.0)
    e1_cost = e1_r1**2 - 2.0 * e1_r1 * at + 1.0
    # Edge r1 = 0: |t + r2 b|² = r2² + 2 r2 b·t + 1.
    e2_r2 = np.maximum(-bt, 0.0)
    e2_cost = e2_r2**2 + 2.0 * e2_r2 * bt + 1.0
    use_e1 = e1_cost <= e2_cost
    new_r1 = np.where(feasible, r1, np.where(use_e1, e1_r1, 0.0))
    new_r2 = np.where(feasible, r2, np.where(use_e1, 0.0, e2_r2))
    return new_r1, new_r2
