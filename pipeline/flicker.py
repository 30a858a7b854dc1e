"""Flicker suppression: a spot that lights up in most frames is not a firefly.

A firefly flash lasts 3–6 frames at 60 fps and the insect moves between flashes, so
even a synchronous species flashing in bursts (flash ~0.1 s every ~0.5 s) lights one
direction in at most ~20% of the frames of a two-second window. Moonlight or a lamp
seen through wind-shaken leaves, a twinkling reflection, or a leaf edge against the
sky keeps re-appearing at the same bearing in a large fraction of frames. Such sources
can pass a patch classifier, which sees one frame only (a crescent of moon peeking past
a leaf looks like a flash), so this temporal test complements it.

The *duty* of a candidate is the number of candidates (its own included) within
``radius_deg`` of its pixel, horizontally wrapping across the 360° seam, in the
``window_s`` centred on its frame, divided by the frames in that window.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from pipeline.params import FlickerParams


def flicker_duty(
    frame: NDArray[np.integer],
    x: NDArray[np.floating],
    y: NDArray[np.floating],
    width: int,
    fps: float,
    radius_deg: float = 1.5,
    window_s: float = 2.0,
) -> NDArray[np.float64]:
    """How often each candidate's spot lights up around its frame.

    Parameters
    ----------
    frame
        (N,) 0-based frame index of each candidate.
    x, y
        (N,) pixel coordinates (DESIGN.md convention), ``0 <= x < width``.
    width
        Frame width in pixels; 360° of azimuth, so ``x`` wraps with this period.
    fps
        Frames per second.
    radius_deg
        Half side of the square neighbourhood, in degrees (``width / 360`` px per degree).
    window_s
        Length of the time window centred on each candidate's frame, in seconds.

    Returns
    -------
    (N,) candidates per frame in each candidate's space-time neighbourhood, counting
    itself; 1.0 means a candidate within the radius in every frame of the window.
    """
    n = len(frame)
    if n == 0:
        return np.zeros(0)
    half = max(1, round(window_s * fps / 2))
    tree = spot_tree(np.asarray(frame, dtype=np.float64) / half, x, y, width, radius_deg)
    counts = tree.query_ball_point(tree.data, r=1.0, p=np.inf, return_length=True)
    return np.asarray(counts, dtype=np.float64) / (2 * half + 1)


def spot_tree(
    t: NDArray[np.floating],
    x: NDArray[np.floating],
    y: NDArray[np.floating],
    width: int,
    radius_deg: float,
) -> cKDTree:
    """A KD-tree of candidates in which "same spot, nearby time" is the unit Chebyshev ball.

    Parameters
    ----------
    t : ndarray of float, shape (N,)
        Time, non-negative, already scaled so that the time neighbourhood is 1.
    x, y : ndarray of float, shape (N,)
        Pixel coordinates, ``0 <= x < width``; ``x`` is periodic (the 360° seam).
    width : int
        Frame width in pixels.
    radius_deg : float
        Spatial radius in degrees (``width / 360`` pixels per degree).
    """
    radius_px = radius_deg * width / 360.0
    period = width / radius_px
    u = np.minimum(
        np.mod(np.asarray(x, dtype=np.float64), width) / radius_px, np.nextafter(period, 0)
    )
    v = np.asarray(y, dtype=np.float64) / radius_px
    v = v - v.min()
    # Time and y get boxes wider than their range plus the radius, so they never wrap.
    box = [float(np.max(t)) + 2.0, period, float(v.max()) + 2.0]
    return cKDTree(np.column_stack([np.asarray(t, dtype=np.float64), u, v]), boxsize=box)


def flickering(duty: NDArray[np.floating], params: FlickerParams) -> NDArray[np.bool_]:
    """(N,) True where a candidate's `flicker_duty` says it sits on a flickering spot.

    All False when ``params.enabled`` is false.
    """
    if not params.enabled:
        return np.zeros(len(duty), dtype=bool)
    return np.asarray(duty > params.max_duty)
