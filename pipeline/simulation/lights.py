"""Artificial lights: lamps, the moon, car head/tail lights and waved flashlights.

Each light is a track over the rig's action frames (camera-1 clock): a 3D position
(or a direction at infinity), a peak luma per camera and a point-spread made of a
sharp core plus a wide glow (lens glare).
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from pipeline.geometry import FloatArray
from pipeline.simulation.render import unit_luma
from pipeline.simulation.rig import Rig

#: Below this peak luma a light is not listed as an artifact.
VISIBLE_LUMA = 8.0
#: Car lamps: height above ground, half track width and half length, metres.
CAR_LAMP_HEIGHT_M = 0.7
CAR_HALF_WIDTH_M = 0.75
CAR_HALF_LENGTH_M = 2.0


@dataclass(frozen=True)
class LightTrack:
    """One light over the action frames.

    Attributes
    ----------
    kind : str
        Artifact label (``lamp``, ``moon``, ``headlight``, ``taillight``, ``flashlight``).
    position : ndarray, shape (n_steps, 3)
        World position in metres, or a unit world direction when ``at_infinity``.
    at_infinity : bool
    peak : ndarray, shape (n_steps, 2)
        Peak luma of the core in camera 1 and camera 2 (0 when off or hidden).
    core_sigma, glow_sigma : float
        Point-spread standard deviations, pixels.
    glow_ratio : float
        Peak of the glow relative to the core's.
    colour : ndarray, shape (3,)
        Unit-luma RGB.
    """

    kind: str
    position: FloatArray
    at_infinity: bool
    peak: FloatArray
    core_sigma: float
    glow_sigma: float
    glow_ratio: float
    colour: FloatArray

    def camera_coordinates(self, rig: Rig, camera: int) -> FloatArray:
        """Positions (or directions) in ``camera``'s frame, shape (n_steps, 3)."""
        if self.at_infinity:
            return rig.directions_to_camera(self.position, camera)
        return rig.to_camera(self.position, camera)


def _ground_point(distance: ArrayLike, azimuth: ArrayLike, height: ArrayLike) -> FloatArray:
    """World points at horizontal ``distance`` and ``azimuth`` (radians), height ``height``."""
    distance, azimuth, height = np.broadcast_arrays(distance, azimuth, height)
    return np.stack([distance * np.cos(azimuth), distance * np.sin(azimuth), height], axis=-1)


def _distance_to_cameras(position: FloatArray, rig: Rig) -> tuple[FloatArray, FloatArray]:
    """Unit vectors from ``position`` (n, 3) towards each camera, shape (n, 2, 3), and
    distances (n, 2)."""
    cameras = np.stack([np.zeros(3), rig.position2])
    towards = cameras[None, :, :] - position[:, None, :]
    distance = np.linalg.norm(towards, axis=-1)
    return towards / distance[..., None], distance


def lamps(rng: np.random.Generator, count: int, rig: Rig, n_steps: int) -> list[LightTrack]:
    """Porch lights / street lamps 15–40 m away: static, saturated, with glow."""
    distance = rng.uniform(15.0, 40.0, count)
    azimuth = rng.uniform(0, 2 * np.pi, count)
    height = rng.uniform(1.8, 3.0, count) - rig.camera_height_m
    position = _ground_point(distance, azimuth, height)
    peak = rng.uniform(500.0, 1500.0, count)
    warm = [[1.0, 0.8, 0.55], [1.0, 0.62, 0.3], [0.95, 0.95, 1.0]]
    return [
        LightTrack(
            kind="lamp",
            position=np.tile(position[i], (n_steps, 1)),
            at_infinity=False,
            peak=np.full((n_steps, 2), peak[i]),
            core_sigma=1.5,
            glow_sigma=float(rng.uniform(5.0, 8.0)),
            glow_ratio=0.1,
            colour=unit_luma(warm[rng.integers(len(warm))]),
        )
        for i in range(count)
    ]


def moon(rng: np.random.Generator, n_steps: int) -> LightTrack:
    """The moon 15–40° above the horizon: an over-exposed blob with a wide halo; it
    does not move measurably in a recording."""
    elevation = np.deg2rad(rng.uniform(15.0, 40.0))
    azimuth = rng.uniform(0, 2 * np.pi)
    direction = np.array(
        [
            np.cos(elevation) * np.cos(azimuth),
            np.cos(elevation) * np.sin(azimuth),
            np.sin(elevation),
        ]
    )
    return LightTrack(
        kind="moon",
        position=np.tile(direction, (n_steps, 1)),
        at_infinity=True,
        peak=np.full((n_steps, 2), 2000.0),
        core_sigma=2.0,
        glow_sigma=12.0,
        glow_ratio=0.05,
        colour=unit_luma([0.95, 0.95, 1.0]),
    )


def _car_lamp(kind: str, position: FloatArray, heading: FloatArray, rig: Rig) -> LightTrack:
    """A headlight (white, bright and glaring when its beam points at a camera) or a
    tail light (dim red, brightest seen from behind) at ``position`` (n_steps, 3)."""
    towards, distance = _distance_to_cameras(position, rig)
    facing = towards @ heading
    falloff = 40.0 / distance
    if kind == "headlight":
        peak = (2500.0 * np.clip(facing, 0, 1) ** 6 + 60.0) * falloff
        core, glow, ratio, rgb = 1.3, 8.0, 0.15, [1.0, 0.97, 0.9]
    else:
        peak = 120.0 * np.clip(-facing, 0.2, 1.0) * falloff
        core, glow, ratio, rgb = 1.0, 3.0, 0.1, [1.0, 0.12, 0.06]
    return LightTrack(
        kind=kind,
        position=position,
        at_infinity=False,
        peak=peak,
        core_sigma=core,
        glow_sigma=glow,
        glow_ratio=ratio,
        colour=unit_luma(rgb),
    )


def cars(
    rng: np.random.Generator, count: int, rig: Rig, fps: float, n_steps: int
) -> list[LightTrack]:
    """Cars driving at 10–18 m/s along a straight road 30–70 m away, seen through gaps
    in the trees; each contributes two headlights and two tail lights."""
    distance = rng.uniform(30.0, 70.0)
    azimuth = rng.uniform(0, 2 * np.pi)
    closest = _ground_point(distance, azimuth, CAR_LAMP_HEIGHT_M - rig.camera_height_m)
    skew = np.deg2rad(rng.uniform(-50.0, 50.0))
    road = np.array([-np.sin(azimuth + skew), np.cos(azimuth + skew), 0.0])
    side = np.cross([0.0, 0.0, 1.0], road)
    gap_phase = rng.uniform(0, 2 * np.pi, 2)
    t = np.arange(n_steps) / fps
    tracks = []
    for _ in range(count):
        heading = road * rng.choice([-1.0, 1.0])
        along = rng.uniform(10.0, 18.0) * (t - rng.uniform(0, n_steps / fps))
        # Trees hide stretches of the road: lights blink on and off as the car passes.
        seen = np.sin(along / 7.0 + gap_phase[0]) + np.sin(along / 3.1 + gap_phase[1]) > -0.4
        seen &= np.abs(along) < 120.0
        centre = closest + along[:, None] * heading
        for lateral, (kind, longitudinal) in itertools.product(
            (-CAR_HALF_WIDTH_M, CAR_HALF_WIDTH_M),
            (("headlight", CAR_HALF_LENGTH_M), ("taillight", -CAR_HALF_LENGTH_M)),
        ):
            lamp = _car_lamp(kind, centre + lateral * side + longitudinal * heading, heading, rig)
            tracks.append(dataclasses.replace(lamp, peak=lamp.peak * seen[:, None]))
    return tracks


def _on_off(
    rng: np.random.Generator, t: FloatArray, on_s: tuple[float, float], off_s: tuple[float, float]
) -> np.ndarray:
    """Boolean switch state at times ``t``: alternating on/off spells of random length."""
    spells = int(np.ceil(t[-1] / (on_s[0] + off_s[0]))) + 2
    lengths = np.column_stack([rng.uniform(*on_s, spells), rng.uniform(*off_s, spells)]).ravel()
    edges = np.cumsum(lengths) - rng.uniform(0, lengths[0] + lengths[1])
    return np.searchsorted(edges, t, side="right") % 2 == 1


def flashlights(
    rng: np.random.Generator, count: int, rig: Rig, fps: float, n_steps: int
) -> list[LightTrack]:
    """People 6–20 m away walking with flashlights switched on and off, the beam
    waved about: it flares whenever it sweeps across a camera."""
    t = np.arange(n_steps) / fps
    tracks = []
    for _ in range(count):
        start = _ground_point(
            rng.uniform(6.0, 20.0), rng.uniform(0, 2 * np.pi), 1.1 - rig.camera_height_m
        )
        walk = Rotation.from_euler("z", rng.uniform(0, 360), degrees=True).apply([0.5, 0.0, 0.0])
        wave_hz = rng.uniform(0.3, 1.0)
        hand = 0.15 * np.column_stack(
            [
                np.sin(2 * np.pi * wave_hz * t),
                np.cos(2 * np.pi * wave_hz * t),
                0.3 * np.sin(4 * np.pi * wave_hz * t),
            ]
        )
        position = start + t[:, None] * walk + hand
        towards, dist = _distance_to_cameras(position, rig)
        to_rig = towards.mean(axis=1)
        yaw = np.arctan2(to_rig[:, 1], to_rig[:, 0]) + np.deg2rad(50.0) * np.sin(
            2 * np.pi * wave_hz * t + rng.uniform(0, 2 * np.pi)
        )
        pitch = np.deg2rad(-15.0 + 12.0 * np.sin(2 * np.pi * 0.37 * wave_hz * t))
        beam = np.column_stack(
            [np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)]
        )
        facing = np.einsum("nkc,nc->nk", towards, beam)
        on = _on_off(rng, t, (1.5, 4.0), (1.0, 5.0))
        peak = (1200.0 * np.clip(facing, 0, 1) ** 10 + 25.0) * (10.0 / dist) * on[:, None]
        tracks.append(
            LightTrack(
                kind="flashlight",
                position=position,
                at_infinity=False,
                peak=peak,
                core_sigma=1.0,
                glow_sigma=5.0,
                glow_ratio=0.12,
                colour=unit_luma([0.9, 0.95, 1.0]),
            )
        )
    return tracks
