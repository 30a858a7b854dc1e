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
``window_s`` centred on its frame, divided by the frames in that window. Only
neighbours about as bright as the candidate count (`FlickerParams.peer_octaves`): a
flickering source relights its spot as brightly as it lit it, while the grain and
foliage candidates around a bright flash are faint. Their density grows with the
resolution (a box of 3° holds 70 times the pixels at 5.7K that it holds at 640 px), and
counted at any brightness they made bright flashes in a wind-swayed band "flicker".
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from pipeline.detections import Detections
from pipeline.params import FlickerParams

#: SNRs are compared on a grid of this many octaves (`flicker_duty`'s ``peer_octaves``).
OCTAVE_STEP = 0.5


def flicker_duty(
    frame: NDArray[np.integer],
    x: NDArray[np.floating],
    y: NDArray[np.floating],
    width: int,
    fps: float,
    radius_deg: float = 1.5,
    window_s: float = 2.0,
    snr: NDArray[np.floating] | None = None,
    peer_octaves: float | None = None,
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
    snr, peer_octaves
        (N,) SNR of each candidate, and how many octaves fainter than a candidate a
        neighbour may be and still count. SNRs are compared on a grid of
        `OCTAVE_STEP` octaves, so 1 octave counts the neighbours from 1/2–1/2.8 of the
        candidate's SNR up. None (either): every neighbour counts; a NaN SNR counts as
        a neighbour of every candidate and has every candidate as its neighbour.

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
    counts = np.zeros(n)
    for query, peers in _peer_groups(snr, peer_octaves, n):
        sub = tree if peers.all() else cKDTree(tree.data[peers], boxsize=tree.boxsize)
        counts[query] = sub.query_ball_point(tree.data[query], r=1.0, p=np.inf, return_length=True)
    return counts / (2 * half + 1)


def candidate_duty(
    candidates: Detections, width: int, fps: float, params: FlickerParams
) -> NDArray[np.float64]:
    """`flicker_duty` of one camera's candidates with the parameters of a run."""
    return flicker_duty(
        candidates.frame,
        candidates.x,
        candidates.y,
        width,
        fps,
        params.radius_deg,
        params.window_s,
        candidates.snr,
        params.peer_octaves,
    )


def _peer_groups(
    snr: NDArray[np.floating] | None, peer_octaves: float | None, n: int
) -> list[tuple[NDArray[np.bool_], NDArray[np.bool_]]]:
    """(candidates queried, the candidates they count) for each level of SNR."""
    everyone = np.ones(n, dtype=bool)
    if snr is None or peer_octaves is None:
        return [(everyone, everyone)]
    with np.errstate(divide="ignore", invalid="ignore"):
        level = np.floor(np.log2(np.asarray(snr, dtype=np.float64)) / OCTAVE_STEP)
    reach = round(peer_octaves / OCTAVE_STEP)
    known = np.isfinite(level)
    groups = [(level == value, ~(level < value - reach)) for value in np.unique(level[known])]
    if not known.all():
        groups.append((~known, everyone))
    return groups


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
