"""Static night landscape seen by each camera: sky, treeline, ground, stars.

Each pixel's ray is cast into a simple 3D world: the flat ground ``z = −h``, a wall of
trees on a vertical cylinder of radius ``TREELINE_DISTANCE_M`` around camera 1 (tops
given by an elevation profile seen from camera 1), and sky and stars at infinity. So
the background shows the same parallax between the cameras as the fireflies do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pipeline.geometry import FloatArray, bearing_to_pixel, pixel_to_bearing
from pipeline.simulation.render import LUMA, add_spots, unit_luma
from pipeline.simulation.rig import Rig

#: Horizontal distance of the treeline from camera 1, metres.
TREELINE_DISTANCE_M = 40.0
#: Azimuth samples of the tabulated treeline profile.
TREELINE_SAMPLES = 4096
#: Distant tree crowns along the treeline: count, half-width and height (degrees).
N_TREES = 140
TREE_HALF_WIDTH_DEG = (1.5, 6.0)
TREE_HEIGHT_DEG = (3.0, 13.0)
#: Elevation of the ground/hedge line between crowns (degrees).
HEDGE_DEG = (1.5, 3.5)
#: Leafy roughness of the crowns' outline: harmonics and RMS elevation (degrees).
ROUGHNESS_HARMONICS = (40, 400)
ROUGHNESS_DEG = 0.35
#: Plane waves summed into the ground/tree texture.
TEXTURE_WAVES = 32
#: Luma of the tree silhouettes and of the ground (before texture).
TREES_LUMA = 3.0
GROUND_LUMA = 5.0
#: Amplitude of the texture, luma.
TEXTURE_LUMA = 2.0
#: Fraction of the sky's brightness reflected by the ground and canopy.
GROUND_ALBEDO = 0.06
#: Sky brightness relative to the horizon: ``ZENITH_FRACTION`` overhead, rising
#: towards the horizon with e-folding elevation ``SKY_GLOW_RAD``.
ZENITH_FRACTION = 0.25
SKY_GLOW_RAD = 0.4
#: Colours (unit luma) of the sky at the horizon and high up, and of vegetation.
HORIZON_RGB = np.array([1.0, 0.82, 0.62])
ZENITH_RGB = np.array([0.55, 0.7, 1.0])
VEGETATION_RGB = np.array([0.9, 1.0, 0.85])
#: Number of stars and their peak luma range; stars fade out in a sky brighter than
#: ``STARS_FADE_LUMA``.
N_STARS = 150
STAR_LUMA = (6.0, 35.0)
STARS_FADE_LUMA = 40.0


@dataclass(frozen=True)
class Landscape:
    """Random far-field scenery, shared by both cameras.

    Attributes
    ----------
    treeline_profile : ndarray, shape (TREELINE_SAMPLES,)
        Elevation (radians) of the top of the treeline at azimuths
        ``2π i / TREELINE_SAMPLES``.
    waves : ndarray, shape (TEXTURE_WAVES, 3)
        Wave vectors (radians per metre) of the texture on ground and trees.
    phases : ndarray, shape (TEXTURE_WAVES,)
    stars : ndarray, shape (N_STARS, 3)
        Unit world directions of stars (only those above the treeline show).
    star_luma : ndarray, shape (N_STARS,)
    """

    treeline_profile: FloatArray
    waves: FloatArray
    phases: FloatArray
    stars: FloatArray
    star_luma: FloatArray

    def treeline(self, azimuth: FloatArray) -> FloatArray:
        """Elevation (radians) of the top of the treeline seen from camera 1 at world
        ``azimuth`` (radians)."""
        grid = np.linspace(0.0, 2 * np.pi, TREELINE_SAMPLES, endpoint=False)
        return np.interp(np.mod(azimuth, 2 * np.pi), grid, self.treeline_profile, period=2 * np.pi)

    def texture(self, directions: FloatArray) -> FloatArray:
        """Zero-mean smooth texture with standard deviation ½ on world directions (..., 3)."""
        waves = np.cos(directions @ self.waves.T + self.phases)
        return waves.sum(axis=-1) / np.sqrt(2.0 * TEXTURE_WAVES)


def treeline_profile(rng: np.random.Generator) -> FloatArray:
    """Treeline elevation (radians) on ``TREELINE_SAMPLES`` azimuths: the upper envelope
    of round (broadleaf) and pointed (conifer) crowns over a low hedge line, with a
    leafy rough outline."""
    grid = np.linspace(0.0, 2 * np.pi, TREELINE_SAMPLES, endpoint=False)
    centre = rng.uniform(0, 2 * np.pi, N_TREES)
    half_width = np.deg2rad(rng.uniform(*TREE_HALF_WIDTH_DEG, N_TREES))
    height = np.deg2rad(rng.uniform(*TREE_HEIGHT_DEG, N_TREES))
    offset = np.abs(np.angle(np.exp(1j * (grid[:, None] - centre)))) / half_width
    inside = np.clip(1.0 - offset, 0.0, 1.0)
    conifer = rng.random(N_TREES) < 0.4
    crowns = height * np.where(conifer, inside, np.sqrt(inside * (2.0 - inside)))
    hedge = np.deg2rad(rng.uniform(*HEDGE_DEG))
    k = np.arange(*ROUGHNESS_HARMONICS)
    coeffs = rng.normal(size=(k.size, 2)) / np.sqrt(k)[:, None]
    rough = np.cos(np.outer(grid, k)) @ coeffs[:, 0] + np.sin(np.outer(grid, k)) @ coeffs[:, 1]
    rough *= np.deg2rad(ROUGHNESS_DEG) / rough.std()
    return np.maximum(hedge, crowns.max(axis=1)) + rough


def draw_landscape(rng: np.random.Generator) -> Landscape:
    """Treeline, vegetation texture and stars."""
    direction = rng.normal(size=(TEXTURE_WAVES, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    # Wavelengths 1–20 m: smooth on the ground nearby, still resolved on the trees.
    frequency = 2 * np.pi / np.exp(rng.uniform(np.log(1.0), np.log(20.0), TEXTURE_WAVES))
    stars = rng.normal(size=(N_STARS, 3))
    stars[:, 2] = np.abs(stars[:, 2])
    return Landscape(
        treeline_profile=treeline_profile(rng),
        waves=direction * frequency[:, None],
        phases=rng.uniform(0, 2 * np.pi, TEXTURE_WAVES),
        stars=stars / np.linalg.norm(stars, axis=1, keepdims=True),
        star_luma=rng.uniform(*STAR_LUMA, N_STARS),
    )


@dataclass(frozen=True)
class CameraBackground:
    """Background layers of one camera, scaled by its exposure gain.

    A frame's background is ``static + sky_level * sky`` (0–255 luma scale per unit
    of ``sky_level``); ``*_luma`` are the luma planes used for shot noise.
    """

    static: NDArray[np.float32]
    sky: NDArray[np.float32]
    static_luma: NDArray[np.float32]
    sky_luma: NDArray[np.float32]

    def frame(self, sky_level: float) -> NDArray[np.float32]:
        """A fresh ``(H, W, 3)`` background image for horizon sky luma ``sky_level``."""
        return self.static + np.float32(sky_level) * self.sky

    def luma(self, sky_level: float) -> NDArray[np.float32]:
        return self.static_luma + np.float32(sky_level) * self.sky_luma


@dataclass(frozen=True)
class RayHits:
    """Where each pixel's ray meets the world.

    Attributes
    ----------
    point : ndarray, shape (H, W, 3)
        First hit on the ground or the treeline cylinder (metres; rays that meet
        neither end far along their direction).
    sky_fraction : ndarray, shape (H, W)
        How much of the pixel sees sky above the trees (anti-aliased over one pixel).
    on_ground : ndarray of bool, shape (H, W)
    """

    point: FloatArray
    sky_fraction: FloatArray
    on_ground: NDArray[np.bool_]


def cast_rays(
    origin: FloatArray, direction: FloatArray, landscape: Landscape, ground_z: float, width: int
) -> RayHits:
    """Intersect rays from ``origin`` along unit world ``direction`` (H, W, 3) with the
    ground plane ``z = ground_z`` and the treeline cylinder."""
    far = 1e6
    dz = direction[..., 2]
    down = dz < -1e-9
    ground_t = np.where(down, (ground_z - origin[2]) / np.where(down, dz, -1.0), far)
    # |origin_xy + t direction_xy| = R, positive root (the origin is inside the cylinder).
    a = np.maximum(direction[..., 0] ** 2 + direction[..., 1] ** 2, 1e-12)
    b = 2.0 * (origin[0] * direction[..., 0] + origin[1] * direction[..., 1])
    c = origin[0] ** 2 + origin[1] ** 2 - TREELINE_DISTANCE_M**2
    wall_t = np.minimum((-b + np.sqrt(b * b - 4.0 * a * c)) / (2.0 * a), far)
    on_ground = ground_t < wall_t
    t = np.minimum(ground_t, wall_t)
    point = origin + t[..., None] * direction
    azimuth = np.arctan2(point[..., 1], point[..., 0])
    top = TREELINE_DISTANCE_M * np.tan(landscape.treeline(azimuth))
    pixel_m = t * (2 * np.pi / width)
    sky_fraction = np.where(on_ground, 0.0, np.clip((point[..., 2] - top) / pixel_m + 0.5, 0, 1))
    return RayHits(point=point, sky_fraction=sky_fraction, on_ground=on_ground)


def camera_background(
    landscape: Landscape, rig: Rig, camera: int, faintest_sky: float
) -> CameraBackground:
    """Render ``landscape`` as seen by ``camera`` (1 or 2).

    ``faintest_sky`` is the lowest horizon sky luma of the recording: stars show in
    proportion to how dark the sky gets.
    """
    rows, cols = np.mgrid[0 : rig.height, 0 : rig.width]
    static, sky = _layers(landscape, rig, camera, rows, cols)
    stars = np.clip(1.0 - faintest_sky / STARS_FADE_LUMA, 0.0, 1.0)
    _add_stars(static, landscape, rig, camera, stars)

    gain = np.float32(rig.gains[camera - 1])
    static *= gain
    static += np.float32(0.5)  # turns the final truncation to uint8 into rounding
    sky_layer = (sky * gain).astype(np.float32)
    return CameraBackground(
        static=static,
        sky=sky_layer,
        static_luma=(static @ LUMA).astype(np.float32),
        sky_luma=(sky_layer @ LUMA).astype(np.float32),
    )


def _layers(
    landscape: Landscape, rig: Rig, camera: int, rows: NDArray, cols: NDArray
) -> tuple[NDArray[np.float32], FloatArray]:
    """Unit-gain static layer (vegetation, float32, no stars) and sky layer (per unit
    of horizon sky luma) of ``camera`` at pixels ``rows``, ``cols`` (any shape)."""
    world = rig.camera_directions_in_world(pixel_to_bearing(cols, rows, rig.width), camera)
    origin = np.zeros(3) if camera == 1 else rig.position2
    hits = cast_rays(origin, world, landscape, -rig.camera_height_m, rig.width)
    sky_fraction = hits.sky_fraction

    elevation = np.arcsin(np.clip(world[..., 2], -1.0, 1.0))
    glow = np.exp(-np.maximum(elevation, 0.0) / SKY_GLOW_RAD)
    colour = unit_luma(glow[..., None] * HORIZON_RGB + (1 - glow[..., None]) * ZENITH_RGB)
    brightness = ZENITH_FRACTION + (1 - ZENITH_FRACTION) * glow
    sky = (sky_fraction * brightness)[..., None] * colour
    sky += ((1 - sky_fraction) * GROUND_ALBEDO)[..., None] * VEGETATION_RGB

    base = np.where(hits.on_ground, GROUND_LUMA, TREES_LUMA)
    texture = TEXTURE_LUMA * landscape.texture(hits.point)
    vegetation = (1 - sky_fraction) * (base + texture)
    static = (vegetation[..., None] * VEGETATION_RGB).astype(np.float32)
    return static, sky


def background_luma_at(
    landscape: Landscape, rig: Rig, camera: int, rows: NDArray, cols: NDArray
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """``static_luma`` and ``sky_luma`` of `camera_background` at pixels ``rows``,
    ``cols`` (1-D), without rendering the whole frame; stars are left out (a few
    faint points)."""
    static, sky = _layers(landscape, rig, camera, rows, cols)
    gain = np.float32(rig.gains[camera - 1])
    static *= gain
    static += np.float32(0.5)
    sky_layer = (sky * gain).astype(np.float32)
    return (static @ LUMA).astype(np.float32), (sky_layer @ LUMA).astype(np.float32)


def _add_stars(
    image: NDArray[np.float32], landscape: Landscape, rig: Rig, camera: int, visibility: float
) -> None:
    """Stars above the treeline as faint, slightly blurred points (``visibility`` scales
    their brightness)."""
    elevation = np.arcsin(landscape.stars[:, 2])
    azimuth = np.arctan2(landscape.stars[:, 1], landscape.stars[:, 0])
    above = elevation > landscape.treeline(azimuth) + np.deg2rad(1.0)
    u, v = bearing_to_pixel(rig.directions_to_camera(landscape.stars[above], camera), rig.width)
    rgb = visibility * landscape.star_luma[above, None] * unit_luma(ZENITH_RGB + 0.6)
    add_spots(image, u, v, np.full(u.size, 0.6), rgb)
