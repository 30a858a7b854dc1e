"""A scenario's scene (landscape, lights, foliage, sky level) and per-camera frame rendering."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from pipeline.geometry import FloatArray, bearing_to_pixel
from pipeline.simulation.background import (
    GROUND_ALBEDO,
    TREES_LUMA,
    VEGETATION_RGB,
    CameraBackground,
    Landscape,
    background_luma_at,
    camera_background,
    draw_landscape,
)
from pipeline.simulation.config import SimulationConfig
from pipeline.simulation.foliage import Foliage, draw_foliage, with_wind
from pipeline.simulation.lights import VISIBLE_LUMA, LightTrack, cars, flashlights, lamps, moon
from pipeline.simulation.render import (
    _window_index,
    add_spots,
    add_streaks,
    apparent_size,
    disc_coverage,
    flash_colour,
    streak_weights,
)
from pipeline.simulation.rig import Rig, stream
from pipeline.simulation.snr import grain_kernel
from pipeline.simulation.tables import ArtifactTruth, FlashTruth

#: Shot noise: variance added per unit of luma (photon noise after gain).
SHOT_NOISE = 0.04
#: Artifact labels reach this many glow σ from a light's centre.
LABEL_SIGMAS = 3.0
#: Candidates within this many pixels of an open sky glint belong to it.
GLINT_LABEL_PX = 3.0


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
                *(
                    self._glint_rows(camera)
                    for camera in (1, 2)
                    if self.foliage is not None and self.foliage.n_glints
                ),
            ]
        )

    def noise_at(
        self,
        camera: int,
        frame: NDArray[np.int64],
        u: FloatArray,
        v: FloatArray,
        read_sigma: float,
        grain_sigma: float = 0.0,
    ) -> FloatArray:
        """σ of the sensor noise `CameraRenderer` adds at the pixel nearest ``(u, v)`` in
        ``camera``'s recorded frame ``frame`` (clamped into the recording): read noise,
        shot noise of the background (stars left out) and grain."""
        rig = self.rig
        rows = np.clip(np.floor(np.asarray(v) + 0.5).astype(np.int64), 0, rig.height - 1)
        cols = np.mod(np.floor(np.asarray(u) + 0.5).astype(np.int64), rig.width)
        static, sky = background_luma_at(self.landscape, rig, camera, rows, cols)
        steps = self.steps(camera)[np.clip(frame, 0, rig.n_frames - 1)]
        level = self.sky_level[steps].astype(np.float32)
        luma = static.astype(np.float64) + level * sky
        variance = read_sigma**2 + SHOT_NOISE * luma + grain_sigma**2
        return np.sqrt(np.maximum(variance, 0.0))

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

    def _glint_rows(self, camera: int) -> ArtifactTruth:
        """Open sky glints (kind ``glint``) per recorded frame of ``camera``."""
        assert self.foliage is not None
        steps = self.steps(camera)
        centres, opening = self.foliage.glints(steps)
        frame, index = np.nonzero(opening > 0)
        u, v = bearing_to_pixel(self.rig.to_camera(centres[frame, index], camera), self.rig.width)
        return ArtifactTruth(
            camera=np.full(len(frame), camera),
            frame=frame,
            u=u,
            v=v,
            radius=np.full(len(frame), GLINT_LABEL_PX),
            kind=np.full(len(frame), "glint"),
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
        if config.sway_px is not None or config.glints_per_branch:
            foliage = with_wind(
                foliage,
                stream(config.seed, "wind"),
                config.fps,
                config.width,
                config.sway_px,
                config.sway_hz,
                config.glints_per_branch,
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
    grain_sigma : float
        Spatially correlated grain, luma σ per pixel (0 = none).
    grain_px : float
        σ in pixels of the Gaussian that correlates the grain.
    grain_rng : numpy.random.Generator, optional
        Source of the grain (required when ``grain_sigma > 0``).
    """

    def __init__(
        self,
        scene: Scene,
        camera: int,
        flashes: FlashTruth,
        noise_sigma: float,
        rng: np.random.Generator,
        grain_sigma: float = 0.0,
        grain_px: float = 1.2,
        grain_rng: np.random.Generator | None = None,
    ) -> None:
        self.scene = scene
        self.camera = camera
        self.rng = rng
        self.noise_sigma = noise_sigma
        self.grain_sigma = grain_sigma
        self.grain_px = grain_px
        self.grain_rng = grain_rng
        if grain_sigma > 0 and grain_rng is None:
            raise ValueError("grain needs its own random generator (grain_rng)")
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
        """The visible flash-frames in frame order, drawn as the truth describes them:
        point-spread, motion streak and colour."""
        frame, u, v, visible = flashes.in_camera(self.camera)
        peak = flashes.camera_column("peak", self.camera)
        order = np.flatnonzero(visible)[np.argsort(frame[visible], kind="stable")]
        self.flash_frame = frame[order]
        self.flash_u, self.flash_v = u[order], v[order]
        self.flash_sigma = flashes.camera_column("psf", self.camera)[order]
        self.flash_du = flashes.camera_column("streak_u", self.camera)[order]
        self.flash_dv = flashes.camera_column("streak_v", self.camera)[order]
        self.flash_rgb = peak[order, None] * flash_colour(flashes.whiteness[order])
        # Still spots are drawn by `add_spots`, exactly as before streaks existed.
        self.streaks = bool(np.any(self.flash_du != 0) or np.any(self.flash_dv != 0))

    def render(self, frame: int) -> NDArray[np.uint8]:
        """Recorded frame ``frame`` (0-based, this camera's numbering), (H, W, 3) uint8."""
        step = int(self.steps[frame])
        level = float(self.scene.sky_level[step])
        image = self.background.frame(level)
        self._draw_lights(image, step)
        self._draw_foliage(image, step, level)
        self._draw_glints(image, step, level)
        lo, hi = np.searchsorted(self.flash_frame, [frame, frame + 1])
        if self.streaks:
            add_streaks(
                image,
                self.flash_u[lo:hi],
                self.flash_v[lo:hi],
                self.flash_sigma[lo:hi],
                self.flash_du[lo:hi],
                self.flash_dv[lo:hi],
                self.flash_rgb[lo:hi],
            )
        else:
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
        if self.grain_sigma > 0:
            image += self._grain()[..., None]
        return np.clip(image, 0.0, 255.0, out=image).astype(np.uint8)

    def _grain(self) -> NDArray[np.float32]:
        """Spatially correlated grain: white noise smoothed by a Gaussian of σ
        ``grain_px`` and rescaled to σ ``grain_sigma`` per pixel."""
        assert self.grain_rng is not None
        shape = self.background.static.shape[:2]
        white = self.grain_rng.standard_normal(shape, dtype=np.float32)
        kernel = grain_kernel(self.grain_px)
        smooth = np.asarray(
            cv2.sepFilter2D(white, -1, kernel, kernel, borderType=cv2.BORDER_REFLECT),
            dtype=np.float32,
        )
        # Smoothing white noise of σ 1 by the separable kernel k leaves σ = Σ k².
        return smooth * np.float32(self.grain_sigma / np.sum(kernel**2))

    def _draw_glints(self, image: NDArray[np.float32], step: int, level: float) -> None:
        """Open leaf holes reveal the sky behind the foliage (the background without it)."""
        foliage, rig = self.scene.foliage, self.scene.rig
        if foliage is None or not foliage.n_glints:
            return
        centres, opening = foliage.glints(step)
        on = opening > 0
        if not np.any(on):
            return
        u, v = bearing_to_pixel(rig.to_camera(centres[on], self.camera), rig.width)
        zero = np.zeros(len(u))
        rows, cols, weight = streak_weights(u, v, foliage.glint_sigma_px[on], zero, zero)
        flat, inside = _window_index(rows, cols, image.shape[:2])
        cover = np.where(inside, weight * opening[on, None, None], 0.0)
        total = np.bincount(flat.ravel(), cover.ravel(), image.shape[0] * image.shape[1])
        index = np.flatnonzero(total)
        fraction = np.minimum(total[index], 1.0).astype(np.float32)[:, None]
        sky = (
            self.background.static.reshape(-1, 3)[index]
            + np.float32(level) * self.background.sky.reshape(-1, 3)[index]
        )
        pixels = image.reshape(-1, 3)
        pixels[index] += fraction * (sky - pixels[index])

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
