"""Wind-shaken foliage: small trees a few metres away whose leafy branches stand
against the sky.

Branches sway slowly, leaves flutter and twist fast (a twisting leaf shows its face,
then its edge), so sky shows through changing gaps:
background subtraction alone sees many flickering bright edges there.

`with_wind` makes it harder (the ``hard-*`` scenarios): branches swing in the wind
with a given amplitude (pixels) and frequency, and small holes between the leaves let
the sky glint through for a frame or two as the leaves move: single bright spots in a
dark canopy, the false positives that look most like a flash.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d

from pipeline.geometry import FloatArray
from pipeline.simulation.rig import Rig

BRANCHES_PER_TREE = 3
LEAVES_PER_BRANCH = 220
#: Horizontal distance of a tree from camera 1 and the elevation of its crown's
#: centre (metres, degrees).
TREE_DISTANCE_M = (3.5, 6.5)
CROWN_ELEVATION_DEG = (22.0, 38.0)
#: Branch centres lie within this radius of the crown's centre, metres.
CROWN_RADIUS_M = 1.1
#: Trunk radius and number of discs drawing it, metres.
TRUNK_RADIUS_M = 0.12
TRUNK_DISCS = 60
#: Semi-axes (x, y, z) of the ellipsoid holding a branch's leaves, metres.
BRANCH_SEMI_AXES_M = np.array([0.7, 0.7, 0.4])
LEAF_RADIUS_M = (0.04, 0.08)
#: RMS sway of a branch (metres) and its time scale (seconds).
SWAY_M = 0.08
SWAY_TIME_S = 0.4
#: Leaf flutter amplitude (metres) and frequency (Hz).
FLUTTER_M = (0.01, 0.03)
FLUTTER_HZ = (1.5, 5.0)
#: Apparent size of a leaf seen edge-on, relative to face-on.
EDGE_ON_FRACTION = 0.3
#: Sky glints through leaf holes: the hole opens while the mean of two cosines at
#: ``GLINT_HZ`` exceeds ``GLINT_THRESHOLD`` (irregular blinks of one to a few frames,
#: open in ~5 % of the frames); at most it uncovers ``GLINT_COVER`` of a Gaussian spot
#: of σ ``GLINT_SIGMA_PX`` pixels.
GLINT_HZ = (1.0, 4.0)
GLINT_THRESHOLD = 0.75
GLINT_COVER = (0.3, 1.0)
GLINT_SIGMA_PX = (0.5, 0.9)
#: Glints lie within this fraction of a branch's leaf ellipsoid (where leaves are dense).
GLINT_SPREAD = 0.7


@dataclass(frozen=True)
class Foliage:
    """Trees near the cameras: static trunks, swaying branches, fluttering leaves.

    Attributes
    ----------
    rest : ndarray, shape (n_leaves, 3)
        Leaf centres at rest, metres (world frame).
    radius : ndarray, shape (n_leaves,)
        Leaf radius, metres.
    branch : ndarray of int64, shape (n_leaves,)
    centre : ndarray, shape (n_branches, 3)
        Branch centres at rest.
    sway : ndarray, shape (n_steps, n_branches, 3)
        Branch displacement per action frame.
    flutter_axis : ndarray, shape (n_leaves, 3)
        Direction times amplitude of each leaf's flutter.
    flutter_omega, flutter_phase : ndarray, shape (n_leaves,)
        Angular frequency per action frame, and phase; leaves twist at the same
        rate with phase ``twist_phase``.
    twist_phase : ndarray, shape (n_leaves,)
    trunk : ndarray, shape (n_trunk_discs, 3)
        Centres of the discs (radius ``TRUNK_RADIUS_M``) drawing the static trunks.
    """

    rest: FloatArray
    radius: FloatArray
    branch: np.ndarray
    centre: FloatArray
    sway: FloatArray
    flutter_axis: FloatArray
    flutter_omega: FloatArray
    flutter_phase: FloatArray
    twist_phase: FloatArray
    trunk: FloatArray
    glint_rest: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    glint_branch: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    glint_omega: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    glint_phase: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    glint_cover: FloatArray = field(default_factory=lambda: np.zeros(0))
    glint_sigma_px: FloatArray = field(default_factory=lambda: np.zeros(0))

    @property
    def n_glints(self) -> int:
        return len(self.glint_rest)

    def glints(self, step: int | np.ndarray) -> tuple[FloatArray, FloatArray]:
        """Centres (…, n_glints, 3) in metres of the leaf holes at action frame(s)
        ``step`` and how open they are (…, n_glints): the fraction of a Gaussian spot
        of σ ``glint_sigma_px`` that shows the sky, 0 when closed."""
        s = np.asarray(step)[..., None, None]
        wave = np.cos(self.glint_omega * s + self.glint_phase).mean(axis=-1)
        opening = np.clip((wave - GLINT_THRESHOLD) / (1.0 - GLINT_THRESHOLD), 0.0, 1.0)
        centres = self.glint_rest + self.sway[step][..., self.glint_branch, :]
        return centres, opening * self.glint_cover

    def discs(self, step: int) -> tuple[FloatArray, FloatArray]:
        """Centres (n, 3) and radii (n,) in metres of all leaves and trunk discs at
        action frame ``step``."""
        angle = self.flutter_omega * step
        flutter = np.sin(angle + self.flutter_phase)[:, None] * self.flutter_axis
        leaves = self.rest + self.sway[step, self.branch] + flutter
        facing = np.abs(np.cos(angle + self.twist_phase))
        radius = self.radius * (EDGE_ON_FRACTION + (1 - EDGE_ON_FRACTION) * facing)
        return (
            np.concatenate([leaves, self.trunk]),
            np.concatenate([radius, np.full(len(self.trunk), TRUNK_RADIUS_M)]),
        )

    def branch_centres(self) -> FloatArray:
        """Branch centres over time, shape (n_steps, n_branches, 3)."""
        return self.centre + self.sway

    @property
    def branch_extent_m(self) -> float:
        """Radius around a branch centre that holds all of its leaves."""
        return float(BRANCH_SEMI_AXES_M.max() + LEAF_RADIUS_M[1] + FLUTTER_M[1])


def _unit_vectors(rng: np.random.Generator, n: int) -> FloatArray:
    direction = rng.normal(size=(n, 3))
    return direction / np.linalg.norm(direction, axis=1, keepdims=True)


def _in_ball(rng: np.random.Generator, n: int, semi_axes: FloatArray | float) -> FloatArray:
    """Points uniform in an ellipsoid: random direction, radius ∝ cube root of a uniform."""
    return _unit_vectors(rng, n) * np.cbrt(rng.uniform(size=n))[:, None] * semi_axes


def draw_foliage(
    rng: np.random.Generator, count: int, rig: Rig, fps: float, n_steps: int
) -> Foliage:
    """``count`` branches on small trees 3.5–6.5 m away, crowns 22–38° above the horizon."""
    n_trees = -(-count // BRANCHES_PER_TREE)
    distance = rng.uniform(*TREE_DISTANCE_M, n_trees)
    azimuth = rng.uniform(0, 2 * np.pi, n_trees)
    crown_height = distance * np.tan(np.deg2rad(rng.uniform(*CROWN_ELEVATION_DEG, n_trees)))
    base = np.column_stack(
        [
            distance * np.cos(azimuth),
            distance * np.sin(azimuth),
            np.full(n_trees, -rig.camera_height_m),
        ]
    )
    crown = base + np.outer(crown_height + rig.camera_height_m, [0.0, 0.0, 1.0])
    tree = np.arange(count) % n_trees
    centre = crown[tree] + _in_ball(rng, count, CROWN_RADIUS_M)
    trunk = (
        base[:, None, :] + np.linspace(0.0, 1.0, TRUNK_DISCS)[:, None] * (crown - base)[:, None, :]
    )

    n = count * LEAVES_PER_BRANCH
    branch = np.repeat(np.arange(count), LEAVES_PER_BRANCH)
    noise = gaussian_filter1d(rng.standard_normal((n_steps, count, 3)), SWAY_TIME_S * fps, axis=0)
    sway = SWAY_M * noise / noise.std(axis=0, keepdims=True) * np.array([1.0, 1.0, 0.5])
    return Foliage(
        rest=centre[branch] + _in_ball(rng, n, BRANCH_SEMI_AXES_M),
        radius=rng.uniform(*LEAF_RADIUS_M, n),
        branch=branch,
        centre=centre,
        sway=sway,
        flutter_axis=_unit_vectors(rng, n) * rng.uniform(*FLUTTER_M, n)[:, None],
        flutter_omega=2 * np.pi * rng.uniform(*FLUTTER_HZ, n) / fps,
        flutter_phase=rng.uniform(0, 2 * np.pi, n),
        twist_phase=rng.uniform(0, 2 * np.pi, n),
        trunk=trunk.reshape(-1, 3),
    )


def wind_sway(
    rng: np.random.Generator,
    centre: FloatArray,
    tree: np.ndarray,
    n_steps: int,
    fps: float,
    width: int,
    amplitude_px: tuple[float, float],
    frequency_hz: tuple[float, float],
) -> FloatArray:
    """Branch displacement (n_steps, n_branches, 3) of trees swinging in the wind.

    Each tree swings at one frequency drawn in ``frequency_hz``; each branch with its
    own amplitude drawn in ``amplitude_px`` (angle seen from camera 1 in equatorial
    pixels of a ``width``-pixel frame) and a phase lag of up to ±0.5 rad, across the
    line of sight and mostly horizontally.
    """
    count = len(centre)
    n_trees = int(tree.max(initial=-1)) + 1
    frequency = rng.uniform(*frequency_hz, n_trees)[tree]
    phase = rng.uniform(0, 2 * np.pi, n_trees)[tree] + rng.uniform(-0.5, 0.5, count)
    distance = np.linalg.norm(centre, axis=1)
    amplitude_m = rng.uniform(*amplitude_px, count) * (2 * np.pi / width) * distance
    sight = centre / distance[:, None]
    across = np.cross([0.0, 0.0, 1.0], sight)
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    up = np.cross(sight, across)
    direction = across + rng.uniform(-0.3, 0.3, count)[:, None] * up
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    t = np.arange(n_steps)[:, None] / fps
    swing = np.sin(2 * np.pi * frequency * t + phase)
    return (amplitude_m * swing)[..., None] * direction


def with_wind(
    foliage: Foliage,
    rng: np.random.Generator,
    fps: float,
    width: int,
    amplitude_px: tuple[float, float] | None,
    frequency_hz: tuple[float, float],
    glints_per_branch: int,
) -> Foliage:
    """``foliage`` swinging in the wind (when ``amplitude_px`` is given) with
    ``glints_per_branch`` sky glints per branch (`Foliage.glints`)."""
    n_steps, count = foliage.sway.shape[:2]
    tree = np.arange(count) % (-(-count // BRANCHES_PER_TREE))  # as `draw_foliage` groups them
    sway = foliage.sway
    if amplitude_px is not None:
        sway = wind_sway(rng, foliage.centre, tree, n_steps, fps, width, amplitude_px, frequency_hz)
    n = count * glints_per_branch
    branch = np.repeat(np.arange(count), glints_per_branch)
    return dataclasses.replace(
        foliage,
        sway=sway,
        glint_rest=foliage.centre[branch] + _in_ball(rng, n, GLINT_SPREAD * BRANCH_SEMI_AXES_M),
        glint_branch=branch,
        glint_omega=2 * np.pi * rng.uniform(*GLINT_HZ, (n, 2)) / fps,
        glint_phase=rng.uniform(0, 2 * np.pi, (n, 2)),
        glint_cover=rng.uniform(*GLINT_COVER, n),
        glint_sigma_px=rng.uniform(*GLINT_SIGMA_PX, n),
    )
