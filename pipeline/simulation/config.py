"""Simulation settings and scenario presets."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Self

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)

#: Scenario name -> one-line description.
SCENARIOS: dict[str, str] = {
    "clean": "dark night sky over a treeline, fireflies only",
    "twilight": "sky brightness ramping down at dusk during the recording",
    "lights": "persistent lamps / porch lights with glow, and the moon",
    "headlights": "car headlights sweeping along a distant road, flashlights switched on "
    "and off and waved about",
    "foliage": "wind-shaken leaves silhouetted against a bright sky: edges flicker in and out",
    "field": "a realistic mix: dusk sky, a lamp, the moon, a car, a flashlight, foliage, occlusion",
    "real3d": "flights and flash timing replayed from real 3D data of fireflies in a tent",
    "hard-clean": "a clean night, but fireflies out to 20 m and dim down to the noise floor, "
    "point-spread 0.6-2 px, motion streaks, yellow-green to near-white flashes, correlated "
    "sensor grain, GoPro-like bitrate",
    "hard-swarm": "the hard fireflies gathered in two swarms 1.4 m across, 3-6 m away, "
    "slow (0.02-0.3 m/s) and flashing in synchrony on a shared beat, as Photinus carolinus "
    "does in the real 3D data",
    "hard-species": "the hard fireflies, each flashing in one of several species' patterns: "
    "quick pulses (30-70 ms), brief flashes in trains, long single flashes (0.25-0.45 s)",
    "hard-noisy": "the hard fireflies on a high-ISO night the encoder cannot keep: read noise of "
    "3.5 grey levels at 0.16 bit/pixel leaves blocky speckle that stays put for frames",
    "hard-wind": "the hard fireflies before a bright sky behind trees swaying 1-6 px at "
    "0.3-2 Hz, with sky glints blinking through holes in the leaves",
    "hard-all": "every artifact at once (dusk sky, lamp, moon, car, flashlight, swaying "
    "foliage with glints, occlusion) with the hard fireflies and high-ISO grain",
}


@dataclass(frozen=True)
class ScenarioSpec:
    """What a scenario puts in the scene besides the fireflies.

    Sky levels are the luma (0–255) of the sky at the horizon at the first and the
    last frame; the sky fades exponentially between them.
    """

    sky_start: float = 6.0
    sky_end: float = 6.0
    n_lamps: int = 0
    moon: bool = False
    n_cars: int = 0
    n_flashlights: int = 0
    n_branches: int = 0
    occlusion: float = 0.0
    noise_sigma: float = 1.5


SCENARIO_SPECS: dict[str, ScenarioSpec] = {
    "clean": ScenarioSpec(),
    "twilight": ScenarioSpec(sky_start=140.0, sky_end=10.0, noise_sigma=2.0),
    "lights": ScenarioSpec(sky_start=10.0, sky_end=10.0, n_lamps=3, moon=True),
    "headlights": ScenarioSpec(sky_start=8.0, sky_end=8.0, n_cars=3, n_flashlights=2),
    "foliage": ScenarioSpec(sky_start=240.0, sky_end=240.0, n_branches=9, noise_sigma=2.0),
    "field": ScenarioSpec(
        sky_start=60.0,
        sky_end=15.0,
        n_lamps=1,
        moon=True,
        n_cars=1,
        n_flashlights=1,
        n_branches=3,
        occlusion=0.1,
        noise_sigma=2.0,
    ),
    "real3d": ScenarioSpec(),
    "hard-clean": ScenarioSpec(noise_sigma=1.0),
    "hard-swarm": ScenarioSpec(noise_sigma=1.0),
    "hard-species": ScenarioSpec(noise_sigma=1.0),
    "hard-noisy": ScenarioSpec(noise_sigma=3.5),
    "hard-wind": ScenarioSpec(sky_start=240.0, sky_end=240.0, n_branches=9, noise_sigma=1.5),
    "hard-all": ScenarioSpec(
        sky_start=60.0,
        sky_end=15.0,
        n_lamps=1,
        moon=True,
        n_cars=1,
        n_flashlights=1,
        n_branches=6,
        occlusion=0.1,
        noise_sigma=2.0,
    ),
}

#: Fireflies harder than the footage we tune on (issue 7): out to 20 m and down to the
#: noise floor, varied point-spread, motion streaks, colours from yellow-green to nearly
#: white, spatially correlated grain and a GoPro-like bitrate.
HARD_FIREFLIES: dict[str, Any] = {
    "range_m": (2.0, 20.0),
    "range_spread": "log",
    "n_fireflies": 15,
    "speed_mps": (0.2, 1.5),
    "intensity_range": (0.003, 1.5),
    "psf_sigma_px": (0.6, 2.0),
    "motion_blur": 1.0,
    "flash_whiteness": (0.0, 1.0),
    "grain_sigma": 1.5,
    "grain_px": 1.2,
    "bits_per_pixel": 0.16,
}


class FlashTiming(BaseModel):
    """How one kind of firefly flashes, in seconds (not frames: a species keeps its
    pattern at any frame rate).

    Attributes
    ----------
    flash_s : (low, high)
        Length of a flash, drawn per flash (at least one frame).
    period_s : (low, high)
        Onset-to-onset spacing of the flashes of a train, drawn per train.
    per_train : (low, high)
        Flashes per train.
    quiet_s : (low, high)
        Quiet time between trains.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    flash_s: tuple[float, float]
    period_s: tuple[float, float]
    per_train: tuple[int, int]
    quiet_s: tuple[float, float]

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        for name in ("flash_s", "period_s", "per_train", "quiet_s"):
            low, high = getattr(self, name)
            if not 0 < low <= high:
                raise ValueError(f"{name} must satisfy 0 < low <= high, got {(low, high)}")
        if self.per_train[1] > 1 and self.flash_s[1] >= self.period_s[0]:
            raise ValueError(
                f"flashes of up to {self.flash_s[1]} s overlap trains spaced from "
                f"{self.period_s[0]} s"
            )
        return self


#: Flash patterns of the ``hard-species`` scenario, one drawn per firefly. Species
#: differ far more than the 0.1–0.2 s trains the other scenarios draw: North American
#: *Photinus* and *Photuris* range from pulses of a few tens of milliseconds a few tenths
#: of a second apart to single flashes of up to half a second every few seconds. The
#: patterns stay within what `pipeline.flicker` and the light-curve test may call a flash
#: (lit under 0.5 s, under 40 % of a 2 s window).
SPECIES_TIMINGS: tuple[FlashTiming, ...] = (
    FlashTiming(flash_s=(0.03, 0.07), period_s=(0.2, 0.4), per_train=(3, 8), quiet_s=(2.0, 6.0)),
    FlashTiming(flash_s=(0.1, 0.2), period_s=(0.5, 1.0), per_train=(3, 8), quiet_s=(3.0, 10.0)),
    FlashTiming(flash_s=(0.25, 0.45), period_s=(1.5, 3.0), per_train=(1, 3), quiet_s=(2.0, 6.0)),
    FlashTiming(flash_s=(0.1, 0.3), period_s=(2.0, 6.0), per_train=(1, 1), quiet_s=(2.0, 7.0)),
)

#: Configuration defaults of a scenario, applied to the fields a configuration does not
#: set explicitly (the original scenarios have none: their defaults are the fields').
SCENARIO_DEFAULTS: dict[str, dict[str, Any]] = {
    "hard-clean": HARD_FIREFLIES,
    "hard-species": {**HARD_FIREFLIES, "n_fireflies": 20, "flash_timings": SPECIES_TIMINGS},
    "hard-noisy": HARD_FIREFLIES,
    "hard-swarm": {
        **HARD_FIREFLIES,
        "n_fireflies": 30,
        "swarms": 2,
        "swarm_radius_m": 0.7,
        "range_m": (3.0, 6.0),
        "speed_mps": (0.02, 0.3),
        "flash_period_s": (0.5, 0.65),
        "flashes_per_train": (4, 10),
        "quiet_gap_s": (2.0, 6.0),
    },
    "hard-wind": {
        **HARD_FIREFLIES,
        "sway_px": (1.0, 6.0),
        "sway_hz": (0.3, 2.0),
        "glints_per_branch": 15,
    },
    "hard-all": {
        **HARD_FIREFLIES,
        "grain_sigma": 3.0,
        "sway_px": (1.0, 6.0),
        "sway_hz": (0.3, 2.0),
        "glints_per_branch": 15,
    },
}

FloatRange = tuple[float, float]
IntRange = tuple[int, int]


class SimulationConfig(BaseModel):
    """Settings of one simulated stereo recording (validated; immutable).

    Distances are in metres, times in seconds unless a name says frames. ``None``
    for ``delay_frames`` / ``rotation_deg`` means drawn from the seed; ``None`` for
    ``occlusion`` / ``noise_sigma`` means the scenario's default.

    Attributes
    ----------
    scenario : str
        A key of `SCENARIOS`.
    seed : int
        Everything random derives from it.
    width : int
        Equirectangular width in pixels (multiple of 4); height ``width // 2``.
    fps : float
        Frame rate of both cameras.
    seconds : float
        Length of each camera's recording (``round(seconds * fps)`` frames).
    separation_m, camera_height_m : float
        Baseline length; height of both cameras above the ground.
    delay_frames : int or None
        Camera-1 frame ``k`` shows the instant of camera-2 frame ``k + delay``;
        drawn within ±1 s when ``None``.
    rotation_deg : float or None
        Angle of camera 2's rotation ``R``; drawn in 1–6° (mostly yaw) when ``None``.
    n_fireflies : int
        Synthetic fireflies (ignored by ``real3d``).
    flash_frames, flash_period_s, flashes_per_train, quiet_gap_s : (low, high)
        Ranges of flash length (frames), flash spacing in a train, flashes per train,
        and quiet time between trains.
    flash_timings : tuple of FlashTiming
        When given, each firefly flashes in one of these patterns (drawn uniformly per
        firefly) instead of the four fields above.
    flash_brightness : float
        Peak luma above the background of a typical flash at 5 m.
    speed_mps, range_m : (low, high)
        Flight speeds; horizontal distances from the rig.
    range_spread : {"uniform", "log"}
        How fireflies spread over ``range_m``: ``uniform`` (most far out in the
        original scenarios' 2–10 m) or ``log`` (log-uniform, so a wide range such as
        2–20 m still has many near fireflies).
    occlusion : float or None
        Fraction of flashes hidden from one camera by vegetation.
    noise_sigma : float or None
        Sensor read noise, luma (shot noise comes on top).
    codec : {"h264", "hevc"}
    crf : int
        Encoder constant rate factor (lower = higher quality).
    chapters : (int, int)
        Chapter files per camera.
    real3d_csv : Path or None
        ``x,y,z,frame`` file (60 fps) replayed by the ``real3d`` scenario.
    real3d_swarms : int
        Stretches of that file replayed at once, each as a swarm at its own azimuth.
    intensity_range : (low, high)
        Factor on the emitted intensity of each firefly (of each flash where fireflies
        are unknown), drawn log-uniformly: ``(1, 1)`` makes them all alike. The peak
        luma grows as its square root (tone curve), falls as ``1 / range``.
    psf_sigma_px : (low, high) or None
        Point-spread σ in pixels drawn uniformly per flash-frame and camera; ``None``:
        0.6–1.5 px growing as a flash comes closer (`render.spot_sigma`).
    motion_blur : float
        Fraction of the frame interval the shutter is open: a moving flash is
        integrated along its path into a streak (0 = instantaneous, no streaks).
    flash_whiteness : (low, high)
        Flash colour per firefly (per flash where unknown), drawn uniformly:
        0 = yellow-green (`render.FIREFLY_RGB`), 1 = nearly white (`render.WHITE_FLASH_RGB`).
    grain_sigma : float
        Spatially correlated sensor grain (high-ISO noise), luma σ per pixel, on top
        of ``noise_sigma`` and shot noise; 0 = none.
    grain_px : float
        Correlation length of the grain: σ in pixels of the Gaussian that smooths it.
    bits_per_pixel : float or None
        Encode at an average bitrate of this many bits per pixel per frame
        (``bits_per_pixel · width · height · fps`` bit/s; a GoPro Max spends ~0.16 at
        5.6K, 80 Mbit/s) instead of the constant quality ``crf``; ``None`` = CRF.
    sway_px : (low, high) or None
        Wind sway of the foliage's branches: amplitude in pixels (at this recording's
        width, seen from camera 1) drawn per branch; ``None`` = the original slow
        random sway (~0.08 m RMS).
    sway_hz : (low, high)
        Sway frequency drawn per branch (with ``sway_px``).
    glints_per_branch : int
        Holes in the leaves per foliage branch through which the sky glints: small
        bright spots that blink open for a frame or two as the leaves move.
    swarms : int
        Synthetic fireflies gather in this many swarms, each a cloud ``swarm_radius_m``
        in radius centred ``range_m`` away, and flash in synchrony: each swarm keeps
        one train-and-gap schedule (``flash_period_s``, ``flashes_per_train``,
        ``quiet_gap_s``) and its members flash on most of its beats. 0: every firefly
        flies and flashes on its own.
    swarm_radius_m : float
        Half the extent of a swarm's cloud (metres, each axis).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    scenario: str = "clean"
    seed: int = Field(0, ge=0)
    width: int = Field(640, ge=64)
    fps: float = Field(30.0, gt=0, le=240)
    seconds: float = Field(20.0, gt=0, le=3600)
    separation_m: float = Field(1.5, gt=0, le=20)
    camera_height_m: float = Field(1.2, gt=0, le=10)
    delay_frames: int | None = None
    rotation_deg: float | None = Field(None, ge=0, le=45)
    n_fireflies: int = Field(10, ge=0, le=1000)
    flash_frames: IntRange = (3, 6)
    flash_period_s: FloatRange = (0.5, 1.0)
    flashes_per_train: IntRange = (3, 8)
    quiet_gap_s: FloatRange = (3.0, 10.0)
    flash_timings: tuple[FlashTiming, ...] = ()
    flash_brightness: float = Field(160.0, gt=0)
    speed_mps: FloatRange = (0.2, 1.0)
    range_m: FloatRange = (2.0, 10.0)
    range_spread: Literal["uniform", "log"] = "uniform"
    occlusion: float | None = Field(None, ge=0, le=1)
    noise_sigma: float | None = Field(None, ge=0, le=50)
    codec: Literal["h264", "hevc"] = "h264"
    crf: int = Field(18, ge=0, le=51)
    chapters: IntRange = (1, 1)
    real3d_csv: Path | None = None
    real3d_swarms: int = Field(3, ge=1, le=12)
    intensity_range: FloatRange = (1.0, 1.0)
    psf_sigma_px: FloatRange | None = None
    motion_blur: float = Field(0.0, ge=0, le=1)
    flash_whiteness: FloatRange = (0.0, 0.0)
    grain_sigma: float = Field(0.0, ge=0, le=50)
    grain_px: float = Field(1.2, gt=0, le=5)
    bits_per_pixel: float | None = Field(None, gt=0, le=24)
    sway_px: FloatRange | None = None
    sway_hz: FloatRange = (0.3, 2.0)
    glints_per_branch: int = Field(0, ge=0, le=1000)
    swarms: int = Field(0, ge=0, le=12)
    swarm_radius_m: float = Field(1.0, gt=0, le=10)

    @model_validator(mode="before")
    @classmethod
    def _scenario_defaults(cls, data: Any) -> Any:
        """Fill the fields ``data`` leaves unset from the scenario's `SCENARIO_DEFAULTS`."""
        if isinstance(data, dict):
            defaults = SCENARIO_DEFAULTS.get(str(data.get("scenario", "clean")), {})
            data = {**defaults, **data}
        return data

    @property
    def height(self) -> int:
        return self.width // 2

    @property
    def n_frames(self) -> int:
        """Frames recorded by each camera."""
        return round(self.seconds * self.fps)

    @property
    def spec(self) -> ScenarioSpec:
        return SCENARIO_SPECS[self.scenario]

    @property
    def resolved_occlusion(self) -> float:
        return self.spec.occlusion if self.occlusion is None else self.occlusion

    @property
    def resolved_noise_sigma(self) -> float:
        return self.spec.noise_sigma if self.noise_sigma is None else self.noise_sigma

    @field_validator("scenario")
    @classmethod
    def _known_scenario(cls, value: str) -> str:
        if value not in SCENARIOS:
            raise ValueError(f"unknown scenario {value!r}; choose one of {', '.join(SCENARIOS)}")
        return value

    @field_validator("width")
    @classmethod
    def _width_multiple_of_four(cls, value: int) -> int:
        if value % 4:
            raise ValueError(
                f"width must be a multiple of 4 (yuv420p needs an even height), got {value}"
            )
        return value

    @field_validator(
        "flash_frames",
        "flash_period_s",
        "flashes_per_train",
        "quiet_gap_s",
        "speed_mps",
        "range_m",
        "intensity_range",
        "psf_sigma_px",
        "sway_px",
        "sway_hz",
    )
    @classmethod
    def _ordered_positive_range(cls, value: tuple | None, info: ValidationInfo) -> tuple | None:
        if value is None:
            return value
        low, high = value
        if not 0 < low <= high:
            raise ValueError(f"{info.field_name} must satisfy 0 < low <= high, got {value}")
        return value

    @field_validator("flash_whiteness")
    @classmethod
    def _fraction_range(cls, value: FloatRange, info: ValidationInfo) -> FloatRange:
        low, high = value
        if not 0 <= low <= high <= 1:
            raise ValueError(f"{info.field_name} must satisfy 0 <= low <= high <= 1, got {value}")
        return value

    @field_validator("chapters")
    @classmethod
    def _at_least_one_chapter(cls, value: IntRange) -> IntRange:
        if min(value) < 1:
            raise ValueError(f"each camera needs at least one chapter file, got {value}")
        return value

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        n = self.n_frames
        if n < 2:
            raise ValueError(f"seconds * fps gives {n} frame(s); need at least 2")
        if self.delay_frames is not None and abs(self.delay_frames) > n // 2:
            raise ValueError(
                f"delay_frames={self.delay_frames} leaves the cameras less than half of "
                f"the {n} frames in common; use |delay_frames| <= {n // 2}"
            )
        if max(self.chapters) > n:
            raise ValueError(f"chapters={self.chapters} exceeds the {n} frames per camera")
        if self.range_m[0] <= self.separation_m / 2:
            raise ValueError(
                f"range_m starts at {self.range_m[0]} m, inside half the camera separation"
            )
        if self.swarms and self.range_m[0] - self.swarm_radius_m <= self.separation_m / 2:
            raise ValueError(
                f"swarms of radius {self.swarm_radius_m} m centred from {self.range_m[0]} m "
                "reach inside half the camera separation"
            )
        if self.swarms and self.flash_timings:
            raise ValueError(
                "a swarm flashes on one beat: swarms and flash_timings exclude each other"
            )
        if self.scenario == "real3d":
            if self.real3d_csv is None:
                raise ValueError("scenario 'real3d' needs real3d_csv (path to x,y,z,frame CSV)")
            if not Path(self.real3d_csv).is_file():
                raise ValueError(f"real3d_csv: file not found: {self.real3d_csv}")
        return self
