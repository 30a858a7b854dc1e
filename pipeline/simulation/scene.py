"""A scenario's scene (landscape, lights, foliage, sky level) and per-camera frame rendering."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pipeline.geometry import FloatArray, bearing_to_pixel
from pipeline.simulation.background import (
    GROUND_ALBEDO,
    TREES_LUMA,
    VEGETATION_RGB,
    CameraBackground,
    Landscape,
    camera_background,
    draw_landscape,
)
from pipeline.simulation.config import SimulationConfig
from pipeline.simulation.foliage import Foliage, draw_foliage
from pipeline.simulation.lights import VISIBLE_LUMA, LightTrack, cars, flashlights, lamps, moon
from pipeline.simulation.render import (
    FIREFLY_RGB,
    add_spots,
    apparent_size,
    disc_coverage,
    spot_sigma,
)
from pipeline.simulation.rig import Rig, stream
from pipeline.simulation.tables import ArtifactTruth, FlashTruth

#: Shot noise: variance added per unit of luma (photon noise after gain).
SHOT_NOISE = 0.04
#: Artifact labels reach this many glow σ from a light's centre.
LABEL_SIGMAS = 3.0


@dataclass(frozen=True)
class Scene:
    """Everything in view except the fireflies, over the rig's action frames.

    Attributes
    ----------
    rig : Rig
    landscape : Landscape
    lights : list of LightTrack
    foliage : Foliage or None
    sky_level : ndarray, shape (n_steps,)
        Horizon sky luma per action frame (step ``i`` is camera-1 frame
        ``rig.action_frames[0] + i``).
    """

    rig: Rig
    landscape: Landscape
    lights: list[LightTrack] = field(default_factory=list)
    foliage: Foliage | None = None
    sky_level: FloatArray = field(default_factory=lambda: np.zeros(0))

    def steps(self, camera: int) -> NDArray[np.int64]:
        """Action step shown by each recorded frame of ``camera``."""
        start, _ = self.rig.action_frames
        shift = self.rig.delay_frames if camera == 2 else 0
        return np.arange(self.rig.n_frames) - shift - start

    def artifacts(self) -> ArtifactTruth:
        """Image positions of every light and foliage branch per recorded frame."""
        return ArtifactTruth.concat(
            [
                *(self._light_rows(light, camera) for light in self.lights for camera in (1, 2)),
                *(self._foliage_rows(camera) for camera in (1, 2) if self.foliage is not None),
            ]
        )

    def _light_rows(self, light: LightTrack, camera: int) -> ArtifactTruth:
        steps = self.steps(camera)
        u, v = bearing_to_pixel(light.camera_coordinates(self.rig, camera)[steps], self.rig.width)
        on = light.peak[steps, camera - 1] >= VISIBLE_LUMA
        return ArtifactTruth(
            camera=np.full(on.sum(), camera),
            frame=np.flatnonzero(on),
            u=u[on],
            v=v[on],
            radius=np.full(on.sum(), LABEL_SIGMAS * max(light.glow_sigma, light.core_sigma)),
            kind=np.full(on.sum(), light.kind),
        )

    def _foliage_rows(self, camera: int) -> ArtifactTruth:
        assert self.foliage is not None
        steps = self.steps(camera)
        centres = self.rig.to_camera(self.foliage.branch_centres()[steps], camera)
        u, v = bearing_to_pixel(centres, self.rig.width)
        distance = np.linalg.norm(centres, axis=-1)
        extent, stretch = apparent_size(self.foliage.branch_extent_m, distance, v, self.rig.width)
        frame = np.broadcast_to(np.arange(len(steps))[:, None], u.shape)
        return ArtifactTruth(
            camera=np.full(u.size, camera),
            frame=frame.ravel(),
            u=u.ravel(),
            v=v.ravel(),
            radius=(extent * stretch + 2.0).ravel(),
            kind=np.full(u.size, "foliage"),
        )


def sky_levels(config: SimulationConfig, n_steps: int) -> FloatArray:
    """Horizon sky luma per action frame: exponential fade from start to end level."""
    spec = config.spec
    fraction = np.linspace(0.0, 1.0, n_steps)
    return spec.sky_start * (spec.sky_end / spec.sky_start) ** fraction


def build_scene(config: SimulationConfig, rig: Rig) -> Scene:
    """Landscape, lights and foliage of ``config.scenario``, random from the seed."""
    spec = config.spec
    start, stop = rig.action_frames
    n_steps = stop - start
    lights: list[LightTrack] = []
    lights += lamps(stream(config.seed, "lamps"), spec.n_lamps, rig, n_steps)
    if spec.moon:
        lights.append(moon(stream(config.seed, "moon"), n_steps))
    if spec.n_cars:
        lights += cars(stream(config.seed, "cars"), spec.n_cars, rig, config.fps, n_steps)
    lights += flashlights(
        stream(config.seed, "flashlights"), spec.n_flashlights, rig, config.fps, n_steps
    )
    foliage = None
    if spec.n_branches:
        foliage = draw_foliage(
            stream(config.seed, "foliage"), spec.n_branches, rig, config.fps, n_steps
        )
    return Scene(
        rig=rig,
        landscape=draw_landscape(stream(config.seed, "landscape")),
        lights=lights,
        foliage=foliage,
        sky_level=sky_levels(config, n_steps),
    )


class CameraRenderer:
    """Renders the recorded frames of one camera as uint8 RGB images.

    Parameters
    ----------
    scene : Scene
    camera : int
        1 or 2.
    flashes : FlashTruth
        Ground truth; the rows visible in this camera are drawn.
    noise_sigma : float
        Read noise, luma; shot noise (``SHOT_NOISE``) is added on top.
    rng : numpy.random.Generator
        Source of the per-frame sensor noise.
    """

    def __init__(
        self,
        scene: Scene,
        camera: int,
        flashes: FlashTruth,
        noise_sigma: float,
        rng: np.random.Generator,
    ) -> None:
        self.scene = scene
        self.camera = camera
        self.rng = rng
        self.noise_sigma = noise_sigma
        self.gain = scene.rig.gains[camera - 1]
        self.background: CameraBackground = camera_background(
            scene.landscape, scene.rig, camera, float(scene.sky_level.min())
        )
        self.steps = scene.steps(camera)
        self._prepare_lights()
        self._prepare_flashes(flashes)
        self._noise_cache: tuple[float, NDArray[np.float32]] | None = None

    def _prepare_lights(self) -> None:
        rig, lights = self.scene.rig, self.scene.lights
        if lights:
            local = np.stack(
                [light.camera_coordinates(rig, self.camera) for light in lights], axis=1
            )
            self.light_u, self.light_v = bearing_to_pixel(local, rig.width)
            self.light_peak = self.gain * np.stack(
                [light.peak[:, self.camera - 1] for light in lights], axis=1
            )
        self.light_rgb = np.array([light.colour for light in lights]).reshape(-1, 3)
        self.core_sigma = np.array([light.core_sigma for light in lights])
        self.glow_sigma = np.array([light.glow_sigma for light in lights])
        self.glow_ratio = np.array([light.glow_ratio for light in lights])

    def _prepare_flashes(self, flashes: FlashTruth) -> None:
        frame, u, v, visible = flashes.in_camera(self.camera)
        peak = flashes.peak1 if self.camera == 1 else flashes.peak2
        local = self.scene.rig.to_camera(flashes.position(), self.camera)
        distance = np.linalg.norm(local, axis=-1)
        order = np.flatnonzero(visible)[np.argsort(frame[visible], kind="stable")]
        self.flash_frame = frame[order]
        self.flash_u, self.flash_v = u[order], v[order]
        self.flash_sigma = spot_sigma(distance[order])
        self.flash_rgb = peak[order, None] * FIREFLY_RGB

    def render(self, frame: int) -> NDArray[np.uint8]:
        """Recorded frame ``frame`` (0-based, this camera's numbering), (H, W, 3) uint8."""
        step = int(self.steps[frame])
        level = float(self.scene.sky_level[step])
        image = self.background.frame(level)
        self._draw_lights(image, step)
        self._draw_foliage(image, step, level)
        lo, hi = np.searchsorted(self.flash_frame, [frame, frame + 1])
        add_spots(
            image,
            self.flash_u[lo:hi],
            self.flash_v[lo:hi],
            self.flash_sigma[lo:hi],
            self.flash_rgb[lo:hi],
        )
        image += (
            self._noise_sigma_map(level)
            * self.rng.standard_normal(image.shape[:2], dtype=np.float32)
        )[..., None]
        return np.clip(image, 0.0, 255.0, out=image).astype(np.uint8)

    def _draw_lights(self, image: NDArray[np.float32], step: int) -> None:
        if not self.scene.lights:
            return
        peak = self.light_peak[step]
        on = peak > 0
        u, v = self.light_u[step, on], self.light_v[step, on]
        rgb = peak[on, None] * self.light_rgb[on]
        add_spots(image, u, v, self.core_sigma[on], rgb)
        add_spots(image, u, v, self.glow_sigma[on], rgb * self.glow_ratio[on, None])

    def _draw_foliage(self, image: NDArray[np.float32], step: int, level: float) -> None:
        foliage, rig = self.scene.foliage, self.scene.rig
        if foliage is None:
            return
        centres, radius_m = foliage.discs(step)
        local = rig.to_camera(centres, self.camera)
        u, v = bearing_to_pixel(local, rig.width)
        distance = np.linalg.norm(local, axis=-1)
        radius, stretch = apparent_size(radius_m, distance, v, rig.width)
        index, cover = disc_coverage(u, v, radius, stretch, image.shape[:2])
        leaf = (self.gain * (TREES_LUMA + GROUND_ALBEDO * level) * VEGETATION_RGB).astype(
            np.float32
        )
        pixels = image.reshape(-1, 3)
        pixels[index] += cover[:, None] * (leaf - pixels[index])

    def _noise_sigma_map(self, level: float) -> NDArray[np.float32]:
        """Per-pixel noise σ: read noise plus shot noise of the background (cached while
        the sky level stays the same)."""
        if self._noise_cache is None or self._noise_cache[0] != level:
            variance = self.noise_sigma**2 + SHOT_NOISE * self.background.luma(level)
            self._noise_cache = (level, np.sqrt(np.maximum(variance, 0.0)).astype(np.float32))
        return self._noise_cache[1]
