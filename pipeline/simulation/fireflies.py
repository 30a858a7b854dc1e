"""Synthetic fireflies: smooth random flights and trains of flashes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from pipeline.geometry import FloatArray
from pipeline.simulation.config import FlashTiming, SimulationConfig
from pipeline.simulation.rig import Rig

#: Lowest and highest flight altitude above the ground, metres.
ALTITUDE_M = (0.2, 3.0)
#: Time scale over which a flight changes direction, seconds.
TURN_TIME_S = 0.7
#: Vertical speed relative to horizontal speed (fireflies mostly cruise level).
VERTICAL_SPEED_RATIO = 0.3
#: Chance that a swarm member flashes on a given beat of its swarm.
SWARM_TURNOUT = 0.7
#: Spread (s) of a member's onset about its swarm's beat: synchronous fireflies
#: flash within a few tens of milliseconds of each other.
SYNC_JITTER_S = 0.03


@dataclass(frozen=True)
class Emissions:
    """Light emitted by fireflies, one row per flash per camera-1 frame.

    Attributes
    ----------
    flash_id, firefly_id : ndarray of int64
        ``firefly_id`` is ``-1`` where unknown.
    frame1 : ndarray of int64
        Camera-1 frame (may be negative: before camera 1 started).
    position : ndarray, shape (n, 3)
        Metres, world (= camera 1) frame.
    intensity : ndarray
        Emitted intensity relative to a typical flash peak.
    """

    flash_id: np.ndarray
    firefly_id: np.ndarray
    frame1: np.ndarray
    position: FloatArray
    intensity: FloatArray

    @classmethod
    def concat(cls, parts: list[Emissions]) -> Emissions:
        """Rows of all ``parts`` (flash ids are taken as they are)."""
        return cls(
            *(
                np.concatenate([getattr(p, name) for p in parts])
                for name in cls.__dataclass_fields__
            )
        )


def fold(x: FloatArray, low: FloatArray | float, high: FloatArray | float) -> FloatArray:
    """Reflect ``x`` back and forth into ``[low, high]`` (a continuous triangle wave)."""
    span = np.asarray(high) - np.asarray(low)
    y = np.mod(x - low, 2.0 * span)
    return low + np.where(y > span, 2.0 * span - y, y)


def flights(rng: np.random.Generator, config: SimulationConfig, rig: Rig) -> FloatArray:
    """Smooth random flight paths over the rig's action frames.

    Velocities are Gaussian-smoothed white noise (turning over ``TURN_TIME_S``),
    scaled to a per-firefly speed in ``config.speed_mps``. The horizontal distance
    from the midpoint between the cameras is reflected into ``[range_lo + s/2,
    far_i]`` (``far_i`` drawn per firefly, so most stay well inside the far limit;
    uniformly in its upper 70 %, or log-uniformly from three times the near limit when
    ``config.range_spread == "log"``) and the altitude into ``ALTITUDE_M``.

    Returns
    -------
    ndarray, shape (n_fireflies, n_action_frames, 3)
        Positions in metres, world frame.
    """
    n, (start, stop) = config.n_fireflies, rig.action_frames
    steps = stop - start
    near = config.range_m[0] + config.separation_m / 2
    far_limit = config.range_m[1] + config.separation_m / 2
    if config.range_spread == "log":
        # Log-uniform: as many fireflies near as far, on a logarithmic scale of range.
        far = np.exp(rng.uniform(np.log(min(3.0 * near, far_limit)), np.log(far_limit), n))
    else:
        far = rng.uniform(near + 0.3 * (far_limit - near), far_limit, n)

    velocity = _velocities(rng, config, n, steps)
    azimuth = rng.uniform(0, 2 * np.pi, n)
    if config.range_spread == "log":
        rho = np.exp(rng.uniform(np.log(near), np.log(far)))
    else:
        rho = rng.uniform(near, far)
    altitude = rng.uniform(*ALTITUDE_M, n)
    start_xy = np.stack([rho * np.cos(azimuth), rho * np.sin(azimuth), altitude], axis=-1)
    path = start_xy[:, None, :] + np.cumsum(velocity, axis=1) / config.fps

    rho_path = np.hypot(path[..., 0], path[..., 1])
    scale = fold(rho_path, near, far[:, None]) / np.maximum(rho_path, 1e-9)
    centre = rig.position2 / 2
    return np.stack(
        [
            centre[0] + path[..., 0] * scale,
            centre[1] + path[..., 1] * scale,
            fold(path[..., 2], *ALTITUDE_M) - rig.camera_height_m,
        ],
        axis=-1,
    )


def swarm_flights(
    rng: np.random.Generator, config: SimulationConfig, rig: Rig
) -> tuple[FloatArray, np.ndarray]:
    """Smooth random flights inside ``config.swarms`` clouds.

    Each swarm's centre lies at a horizontal distance drawn in ``config.range_m`` from
    the midpoint between the cameras, at a random azimuth, ``swarm_radius_m`` above the
    lowest altitude of `ALTITUDE_M`; each firefly joins a swarm at random and its
    flight (as in `flights`) is reflected into the box of half-side ``swarm_radius_m``
    about its centre.

    Returns
    -------
    positions : ndarray, shape (n_fireflies, n_action_frames, 3)
        Metres, world frame.
    swarm : ndarray of int64, shape (n_fireflies,)
        The swarm of each firefly.
    """
    n, (start, stop) = config.n_fireflies, rig.action_frames
    radius = config.swarm_radius_m
    swarm = rng.integers(0, config.swarms, n)
    azimuth = rng.uniform(0, 2 * np.pi, config.swarms)
    distance = rng.uniform(*config.range_m, config.swarms)
    centre = np.column_stack(
        [
            rig.position2[0] / 2 + distance * np.cos(azimuth),
            rig.position2[1] / 2 + distance * np.sin(azimuth),
            np.full(config.swarms, ALTITUDE_M[0] + radius - rig.camera_height_m),
        ]
    )[swarm]
    start_xyz = centre + rng.uniform(-radius, radius, (n, 3))
    velocity = _velocities(rng, config, n, stop - start)
    path = start_xyz[:, None, :] + np.cumsum(velocity, axis=1) / config.fps
    return fold(path, centre[:, None] - radius, centre[:, None] + radius), swarm


def _velocities(
    rng: np.random.Generator, config: SimulationConfig, n: int, steps: int
) -> FloatArray:
    """Gaussian-smoothed white-noise velocities (m/frame × fps), each firefly's scaled to
    a horizontal RMS speed drawn in ``config.speed_mps``; shape (n, steps, 3)."""
    velocity = gaussian_filter1d(
        rng.standard_normal((n, steps, 3)), TURN_TIME_S * config.fps, axis=1
    )
    velocity[..., 2] *= VERTICAL_SPEED_RATIO
    rms = np.sqrt(np.mean(np.sum(velocity[..., :2] ** 2, axis=-1), axis=1))
    return velocity * (rng.uniform(*config.speed_mps, n) / rms)[:, None, None]


def expand(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group index and rank within the group of ``sum(counts)`` items, where group
    ``g`` holds ``counts[g]`` consecutive items."""
    group = np.repeat(np.arange(counts.size), counts)
    return group, np.arange(group.size) - np.repeat(np.cumsum(counts) - counts, counts)


def flash_onsets(
    rng: np.random.Generator,
    n: int,
    per_train: tuple[int, int],
    period_s: tuple[float, float],
    quiet_s: tuple[float, float],
    start_s: float,
    stop_s: float,
) -> tuple[np.ndarray, FloatArray]:
    """Onset times of flash trains separated by quiet gaps.

    Each of `n` fireflies alternates quiet gaps (``quiet_s``) and trains of
    ``per_train`` flashes ``period_s`` apart (period drawn per train, jittered by 3 %
    per flash), starting at a random phase.

    Returns
    -------
    firefly_id : ndarray of int64
        In ``[0, n)``.
    onset_s : ndarray
        Seconds on camera 1's clock, within ``[start_s, stop_s)``, sorted.
    """
    lo_n, hi_n = per_train
    shortest_cycle = quiet_s[0] + (lo_n - 1) * period_s[0]
    n_trains = int(np.ceil((stop_s - start_s) / shortest_cycle)) + 2
    mean_cycle = np.mean(quiet_s) + (np.mean([lo_n, hi_n]) - 1) * np.mean(period_s)

    count = rng.integers(lo_n, hi_n + 1, (n, n_trains))
    period = rng.uniform(*period_s, (n, n_trains))
    gap = rng.uniform(*quiet_s, (n, n_trains))
    cycle = (count - 1) * period + gap
    first = start_s - rng.uniform(0, mean_cycle, n)
    train_start = first[:, None] + np.cumsum(cycle, axis=1) - cycle

    train, index_in_train = expand(count.ravel())
    jitter = 1.0 + 0.03 * rng.standard_normal(train.size)
    onset = train_start.ravel()[train] + index_in_train * period.ravel()[train] * jitter
    return _in_window(train // n_trains, onset, start_s, stop_s)


def config_onsets(
    rng: np.random.Generator, config: SimulationConfig, n: int, start_s: float, stop_s: float
) -> tuple[np.ndarray, FloatArray]:
    """`flash_onsets` of `n` fireflies on the configuration's one pattern."""
    return flash_onsets(
        rng, n, config.flashes_per_train, config.flash_period_s, config.quiet_gap_s, start_s, stop_s
    )


def species_flashes(
    rng: np.random.Generator,
    timings: tuple[FlashTiming, ...],
    n: int,
    fps: float,
    start_s: float,
    stop_s: float,
) -> tuple[np.ndarray, FloatArray, np.ndarray]:
    """Flashes of `n` fireflies, each keeping one of the `timings` (drawn uniformly).

    Returns
    -------
    firefly_id : ndarray of int64
    onset_s : ndarray
        Seconds on camera 1's clock, within ``[start_s, stop_s)``, sorted.
    length : ndarray of int64
        Frames each flash lasts: its drawn length in seconds at `fps`, at least one.
    """
    kind = rng.integers(0, len(timings), n)
    parts = []
    for k, timing in enumerate(timings):
        members = np.flatnonzero(kind == k)
        member, onset = flash_onsets(
            rng, members.size, timing.per_train, timing.period_s, timing.quiet_s, start_s, stop_s
        )
        length = np.maximum(1, np.rint(rng.uniform(*timing.flash_s, onset.size) * fps))
        parts.append((members[member], onset, length.astype(np.int64)))
    firefly, onset, length = (np.concatenate(column) for column in zip(*parts, strict=True))
    order = np.argsort(onset, kind="stable")
    return firefly[order], onset[order], length[order]


def synchronous_onsets(
    rng: np.random.Generator,
    config: SimulationConfig,
    swarm: np.ndarray,
    start_s: float,
    stop_s: float,
) -> tuple[np.ndarray, FloatArray]:
    """Onset times of fireflies flashing in synchrony with their swarm.

    Each swarm keeps the schedule `config_onsets` gives one firefly (trains of beats
    separated by quiet gaps); each member flashes on a beat with probability
    `SWARM_TURNOUT`, `SYNC_JITTER_S` off it.

    Returns
    -------
    firefly_id : ndarray of int64
    onset_s : ndarray
        Seconds on camera 1's clock, within ``[start_s, stop_s)``, sorted.
    """
    n_swarms = config.swarms
    beat_swarm, beat_s = config_onsets(rng, config, n_swarms, start_s, stop_s)
    members = np.argsort(swarm, kind="stable")
    size = np.bincount(swarm, minlength=n_swarms)
    beat, rank = expand(size[beat_swarm])
    firefly = members[(np.cumsum(size) - size)[beat_swarm[beat]] + rank]
    onset = beat_s[beat] + SYNC_JITTER_S * rng.standard_normal(beat.size)
    turned_out = rng.random(beat.size) < SWARM_TURNOUT
    return _in_window(firefly[turned_out], onset[turned_out], start_s, stop_s)


def _in_window(
    firefly: np.ndarray, onset: FloatArray, start_s: float, stop_s: float
) -> tuple[np.ndarray, FloatArray]:
    """The onsets within ``[start_s, stop_s)`` and their fireflies, sorted by onset."""
    keep = (onset >= start_s) & (onset < stop_s)
    order = np.argsort(onset[keep], kind="stable")
    return firefly[keep][order].astype(np.int64), onset[keep][order]


def flash_profile(length: np.ndarray) -> tuple[np.ndarray, np.ndarray, FloatArray]:
    """Frame offsets and rise/fall envelope of flashes lasting ``length`` frames.

    Returns the flash index of every flash-frame, its offset from the onset and
    ``sin(π (i + ½) / n)^½``: a fast rise, a plateau and a fall, the first and last
    frames partly exposed.
    """
    flash, offset = expand(length)
    envelope = np.sqrt(np.sin(np.pi * (offset + 0.5) / length[flash]))
    return flash, offset, envelope


def synthetic_emissions(config: SimulationConfig, rig: Rig, rng: np.random.Generator) -> Emissions:
    """Flash-frames of ``config.n_fireflies`` synthetic fireflies over the action frames."""
    start, stop = rig.action_frames
    start_s, stop_s = start / config.fps, stop / config.fps
    if config.flash_timings:  # never with swarms (`SimulationConfig`)
        paths = flights(rng, config, rig)
        firefly, onset_s, length = species_flashes(
            rng, config.flash_timings, config.n_fireflies, config.fps, start_s, stop_s
        )
    else:
        if config.swarms:
            paths, swarm = swarm_flights(rng, config, rig)
            firefly, onset_s = synchronous_onsets(rng, config, swarm, start_s, stop_s)
        else:
            paths = flights(rng, config, rig)
            firefly, onset_s = config_onsets(rng, config, config.n_fireflies, start_s, stop_s)
        lo, hi = config.flash_frames
        length = rng.integers(lo, hi + 1, firefly.size)
    strength = rng.lognormal(0.0, 0.3, firefly.size)
    flash, offset, envelope = flash_profile(length)
    frame1 = np.floor(onset_s * config.fps).astype(np.int64)[flash] + offset
    keep = frame1 < stop
    flash, frame1 = flash[keep], frame1[keep]
    return Emissions(
        flash_id=flash.astype(np.int64),
        firefly_id=firefly[flash],
        frame1=frame1,
        position=paths[firefly[flash], frame1 - start],
        intensity=strength[flash] * envelope[keep],
    )
