"""Flights and flash timing replayed from real 3D flash data (``x,y,z,frame`` CSV)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from pipeline.geometry import FloatArray
from pipeline.simulation.fireflies import Emissions, flash_profile
from pipeline.simulation.rig import Rig

#: Frame rate of the real data.
REAL_FPS = 60.0
#: Consecutive points of one flash are at most this far apart (metres) ...
STREAK_STEP_M = 0.1
#: ... and at most this many real frames apart.
STREAK_GAP_FRAMES = 2
#: Horizontal distance from the rig to the replayed swarm's centre, metres.
SWARM_DISTANCE_M = (3.5, 5.0)
#: Altitude of the swarm's lowest point above the ground, metres.
SWARM_FLOOR_M = 0.3


def read_xyzt(path: str | Path) -> FloatArray:
    """Read ``x,y,z,frame`` rows (metres, integer frames, no header).

    Raises
    ------
    ValueError
        Naming the file when it does not hold four numeric columns with integer,
        non-decreasing frames.
    """
    try:
        data = np.loadtxt(path, delimiter=",", ndmin=2)
    except ValueError as exc:
        raise ValueError(f"{path}: expected numeric x,y,z,frame rows: {exc}") from None
    if data.shape[1] != 4 or len(data) == 0:
        raise ValueError(f"{path}: expected x,y,z,frame rows, got shape {data.shape}")
    frame = data[:, 3]
    if not np.all(frame == np.round(frame)) or np.any(np.diff(frame) < 0):
        raise ValueError(f"{path}: column 4 (frame) must hold non-decreasing integers")
    return data


def link_streaks(position: FloatArray, frame: np.ndarray) -> np.ndarray:
    """Label the points of each flash: points up to ``STREAK_GAP_FRAMES`` frames and
    ``STREAK_STEP_M`` metres apart belong to the same flash (connected components).

    Returns
    -------
    ndarray of int64
        Flash label per point, numbered in order of first appearance.
    """
    time_scale = STREAK_STEP_M / STREAK_GAP_FRAMES
    coords = np.column_stack([position, frame * time_scale])
    pairs = cKDTree(coords).query_pairs(np.sqrt(2) * STREAK_STEP_M, output_type="ndarray")
    df = np.abs(frame[pairs[:, 0]] - frame[pairs[:, 1]])
    dx = np.linalg.norm(position[pairs[:, 0]] - position[pairs[:, 1]], axis=1)
    pairs = pairs[(df >= 1) & (df <= STREAK_GAP_FRAMES) & (dx <= STREAK_STEP_M)]
    n = len(frame)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    _, first, renumbered = np.unique(labels, return_index=True, return_inverse=True)
    return np.argsort(np.argsort(first))[renumbered].astype(np.int64)


def busiest_windows(frame: np.ndarray, length: int, count: int) -> list[int]:
    """First frames of up to ``count`` non-overlapping ``length``-frame windows holding
    the most points, busiest first."""
    counts = np.bincount((frame - frame.min()).astype(np.int64), minlength=length)
    totals = np.convolve(counts, np.ones(length, dtype=np.int64), mode="valid")
    starts: list[int] = []
    while len(starts) < count and totals.max() >= 0:
        best = int(np.argmax(totals))
        starts.append(int(frame.min()) + best)
        totals[max(0, best - length + 1) : best + length] = -1
    return starts


def place_swarm(
    rng: np.random.Generator, position: FloatArray, rig: Rig, azimuth: float
) -> FloatArray:
    """Turn a swarm about the vertical and move it a few metres from the rig towards
    ``azimuth`` (radians), its lowest point ``SWARM_FLOOR_M`` above the ground."""
    turned = Rotation.from_euler("z", rng.uniform(0, 360), degrees=True).apply(position)
    centre_xy = rig.position2[:2] / 2 + rng.uniform(*SWARM_DISTANCE_M) * np.array(
        [np.cos(azimuth), np.sin(azimuth)]
    )
    shift = np.array(
        [
            *(centre_xy - turned[:, :2].mean(axis=0)),
            SWARM_FLOOR_M - rig.camera_height_m - turned[:, 2].min(),
        ]
    )
    return turned + shift


def resample(
    data: FloatArray, first: int, fps: float, span: int
) -> tuple[np.ndarray, np.ndarray, FloatArray, FloatArray]:
    """Real points of frames ``first + [0, span · REAL_FPS / fps)`` as simulated
    flash-frames.

    Each simulated frame integrates the real frames within its exposure interval: a
    flash's position is the mean of its real points in that interval.

    Returns
    -------
    flash : ndarray of int64
        Flash label (0-based, in order of first appearance).
    offset : ndarray of int64
        Simulated frame from the window's start, in ``[0, span)``.
    position : ndarray, shape (n, 3)
        Metres, the data's own frame.
    envelope : ndarray
        Rise/fall profile over each flash's frames (`flash_profile`).
    """
    real_length = int(np.ceil(span * REAL_FPS / fps))
    data = data[(data[:, 3] >= first) & (data[:, 3] < first + real_length)]
    streak = link_streaks(data[:, :3], data[:, 3])
    sim_frame = np.floor((data[:, 3] - first) * fps / REAL_FPS).astype(np.int64)
    # One row per (flash, simulated frame), streak-major: the order flash_profile expects.
    key, row = np.unique(streak * span + sim_frame, return_inverse=True)
    weight = np.bincount(row)
    mean = np.stack([np.bincount(row, data[:, i]) / weight for i in range(3)], axis=-1)
    flash = key // span
    _, _, envelope = flash_profile(np.bincount(flash))
    return flash, key % span, mean, envelope


def real_emissions(
    path: str | Path, fps: float, rig: Rig, rng: np.random.Generator, swarms: int
) -> Emissions:
    """Replay the busiest stretches of real data over the rig's action frames.

    The ``swarms`` busiest non-overlapping stretches of the recording each become a
    swarm a few metres from the rig, spread evenly in azimuth: one tent-sized swarm
    covers a few degrees of the sphere, too little to calibrate a 360° rig, while
    real field swarms surround the cameras. Intensity follows the same rise/fall
    profile as synthetic flashes with a per-flash strength. Firefly identities are
    not in the data (``firefly_id = -1``).
    """
    data = read_xyzt(path)
    start, stop = rig.action_frames
    span = stop - start
    real_length = int(np.ceil(span * REAL_FPS / fps))
    heading = rng.uniform(0, 2 * np.pi)
    parts = []
    n_flashes = 0
    windows = busiest_windows(data[:, 3], real_length, swarms)
    for i, first in enumerate(windows):
        flash, offset, position, envelope = resample(data, first, fps, span)
        azimuth = heading + 2 * np.pi * i / len(windows) + rng.uniform(-0.3, 0.3)
        strength = rng.lognormal(0.0, 0.3, flash.max() + 1)
        parts.append(
            Emissions(
                flash_id=n_flashes + flash,
                firefly_id=np.full(flash.size, -1, dtype=np.int64),
                frame1=start + offset,
                position=place_swarm(rng, position, rig, azimuth),
                intensity=strength[flash] * envelope,
            )
        )
        n_flashes += int(flash.max()) + 1
    return Emissions.concat(parts)
