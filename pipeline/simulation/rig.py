"""The stereo rig: relative pose, frame delay, exposure and projection into each camera."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from pipeline.geometry import FloatArray, Pose, bearing_to_pixel
from pipeline.simulation.config import SimulationConfig


def stream(seed: int, name: str) -> np.random.Generator:
    """Independent random stream per (seed, purpose).

    Separate streams keep, e.g., the pose unchanged when the number of fireflies
    changes.
    """
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


@dataclass(frozen=True)
class Rig:
    """Two 360° cameras side by side (DESIGN.md conventions).

    Attributes
    ----------
    pose : Pose
        ``R`` and ``t̂`` of camera 2 relative to camera 1 (the world frame).
    separation_m : float
        ``|T|``, metres.
    camera_height_m : float
        Height of both cameras above the flat ground ``z = −h``.
    delay_frames : int
        Camera-1 frame ``k`` shows the same instant as camera-2 frame ``k + delay``.
    n_frames : int
        Frames recorded by each camera.
    width : int
        Equirectangular width ``W``; the height is ``W // 2``.
    gains : tuple of float
        Exposure gain of each camera (the two models do not match exactly).
    """

    pose: Pose
    separation_m: float
    camera_height_m: float
    delay_frames: int
    n_frames: int
    width: int
    gains: tuple[float, float]

    @property
    def height(self) -> int:
        return self.width // 2

    @property
    def position2(self) -> FloatArray:
        """``T``, camera 2's centre in the world frame (metres)."""
        return self.separation_m * self.pose.translation

    @property
    def action_frames(self) -> tuple[int, int]:
        """Camera-1 frame range ``[start, stop)`` covering both recordings."""
        return min(0, -self.delay_frames), max(self.n_frames, self.n_frames - self.delay_frames)

    def camera_frames(self, frame1: ArrayLike, camera: int) -> np.ndarray:
        """Frame index in ``camera`` (1 or 2) of camera-1 frames ``frame1``."""
        f = np.asarray(frame1, dtype=np.int64)
        return f if camera == 1 else f + self.delay_frames

    def to_camera(self, points: ArrayLike, camera: int) -> FloatArray:
        """Coordinates of world points (metres, shape (..., 3)) in ``camera``'s frame."""
        if camera == 1:
            return np.asarray(points, dtype=np.float64)
        return self.pose.world_to_camera2(points, self.separation_m)

    def directions_to_camera(self, directions: ArrayLike, camera: int) -> FloatArray:
        """Directions at infinity (world frame) expressed in ``camera``'s frame."""
        d = np.asarray(directions, dtype=np.float64)
        return d if camera == 1 else d @ self.pose.rotation.T

    def camera_directions_in_world(self, bearings: ArrayLike, camera: int) -> FloatArray:
        """World directions of ``camera``'s bearings."""
        b = np.asarray(bearings, dtype=np.float64)
        return b if camera == 1 else self.pose.camera2_directions_in_world(b)

    def project(self, points: ArrayLike, camera: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Pixel position and range of world points in ``camera``.

        Returns
        -------
        u, v : ndarray
            Equirectangular pixel position (`pipeline.geometry.bearing_to_pixel`).
        range_m : ndarray
            Distance from that camera's centre, metres.
        """
        local = self.to_camera(points, camera)
        u, v = bearing_to_pixel(local, self.width)
        return u, v, np.linalg.norm(local, axis=-1)


def draw_pose(rng: np.random.Generator, rotation_deg: float | None) -> Pose:
    """Side-by-side, roughly parallel pose.

    ``t̂`` is ±x or ±y tilted by a few degrees; ``R`` turns by ``rotation_deg``
    (drawn in 1–6° when ``None``) about an axis close to vertical: mostly yaw.
    """
    base = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0]])[rng.integers(4)]
    azimuth = Rotation.from_euler("z", rng.normal(0.0, 3.0), degrees=True)
    pitch = Rotation.from_rotvec(np.deg2rad(rng.normal(0.0, 2.0)) * np.cross(base, [0, 0, 1]))
    angle = np.deg2rad(rng.uniform(1.0, 6.0) if rotation_deg is None else rotation_deg)
    axis = np.array([*rng.normal(0.0, 0.25, 2), rng.choice([-1.0, 1.0])])
    rotation = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
    return Pose(rotation=rotation, translation=(azimuth * pitch).apply(base))


def draw_rig(config: SimulationConfig) -> Rig:
    """Pose, delay and camera gains for ``config``, random where it leaves them open."""
    rng = stream(config.seed, "rig")
    pose = draw_pose(rng, config.rotation_deg)
    n = config.n_frames
    one_second = round(config.fps)
    drawn_delay = int(rng.integers(-one_second, one_second + 1))
    delay = config.delay_frames
    if delay is None:
        delay = int(np.clip(drawn_delay, -(n // 2), n // 2))
    gains = (1.0, float(rng.uniform(0.85, 1.15)))
    return Rig(
        pose=pose,
        separation_m=config.separation_m,
        camera_height_m=config.camera_height_m,
        delay_frames=delay,
        n_frames=n,
        width=config.width,
        gains=gains,
    )
