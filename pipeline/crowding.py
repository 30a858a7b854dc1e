"""Seeds a brighter spot hides: flashes a few pixels from another (a swarm).

Two flashes 3–6 px apart make one blob of the matched filter's response, and the fainter
one is often no local maximum at all, only a shoulder on the brighter one's slope: on
the simulated swarm tuning night (hard-swarm s12, 640 px, camera 1) 0.72 of the
flash-frames of ≥ 5 σ had a candidate (0.80 with these seeds), 0.45–0.52 of those with
another flash 3–6 px away. Each peak's spot is fitted with a Gaussian through its pixel
and four neighbours, its light is taken off the blob, and what still rises to the seed
level as a local maximum, away from every peak, and is itself a spot, is a seed of its
own (docs/detection.md, "Crowded flashes").

Only blobs whose every peak is a compact Gaussian spot are looked into: a glint on a
swaying leaf or a lamp's rim is not a Gaussian, and what is left of it after taking a
Gaussian off would be its own clutter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from pipeline.blobs import (
    CROSS,
    PixelIndex,
    climb_to_maximum,
    gaussian_spots,
    local_maxima,
    spots_light,
    window_indices,
    wrap_columns,
)

#: Widest spot fitted, σ in pixels of the recording: the matched filter (σ 1 px) over
#: the widest simulated point spread (2 px) gives 2.24 px; wider is not a point.
MAX_SPOT_SIGMA_PX = 2.5
#: Narrowest spot a seed may be, σ in pixels of the recording: the matched filter alone
#: spreads a point over 1 px, so a residual much narrower is the edge of a spot the
#: fit got wrong (a light that moved: the dark hollow it left bends its fit).
MIN_SPOT_SIGMA_PX = 0.5
#: A seed closer than this to a peak's centre is that peak's own light, pixels.
MIN_SEPARATION_PX = 1.5
#: Fewest σ a seed has of its own for each σ of its nearest peak: a moving flash's
#: streak, or a spot the encoder smeared, is no Gaussian either, and leaves a tenth of
#: its light or less beside it when one is taken off (tuning nights, 640 px, camera 1:
#: it drops 52 of the 96 false seeds of hard-clean s12-13, and 30 of the 155 seeds of
#: hard-swarm s12, 16 of them true).
MIN_SHARE = 0.1
#: How far a spot's light is taken off, in its widest σ.
REACH_SIGMAS = 3.0


@dataclass(frozen=True)
class CrowdedSeeds:
    """Seeds found beside brighter spots (`crowded_seeds`).

    Attributes
    ----------
    at : ndarray of intp
        Their positions in the frame's pixel list.
    snr : ndarray of float64
        Their own SNR: the response less the neighbours' light, in units of the noise.
    row, col : ndarray of float64
        Their sub-pixel centres, fitted on that residual light (image pixels).
    """

    at: NDArray[np.intp]
    snr: NDArray[np.float64]
    row: NDArray[np.float64]
    col: NDArray[np.float64]

    @classmethod
    def empty(cls) -> CrowdedSeeds:
        return cls(np.zeros(0, np.intp), *(np.zeros(0) for _ in range(3)))


def crowded_seeds(
    pixels: PixelIndex,
    idx: NDArray[np.intp],
    snr: NDArray[np.float64],
    response: NDArray[np.float32],
    blobs: NDArray[np.intp],
    peaks: NDArray[np.bool_],
    threshold: float,
    bin_px: int,
) -> CrowdedSeeds:
    """Local maxima that reach `threshold` once the blob's peaks' spots are taken off.

    Parameters
    ----------
    pixels : PixelIndex
        The frame's pixels above the extent level (assigned `idx`).
    idx : ndarray of intp, shape (N,)
        Their flat indices, ascending.
    snr : ndarray of float64, shape (N,)
        Their response over the noise σ.
    response : ndarray of float32, shape (H, W)
        The matched filter's response, grey levels (columns wrap at the 360° seam).
    blobs : ndarray of intp, shape (N,)
        Each pixel's blob.
    peaks : ndarray of bool, shape (N,)
        The blobs' seeds (oversized blobs' excluded).
    threshold : float
        The seed level, σ.
    bin_px : int
        Bin side of `response` in pixels of the recording.
    """
    at = np.flatnonzero(peaks)
    if len(at) == 0:
        return CrowdedSeeds.empty()
    width = response.shape[1]
    spots = gaussian_spots(response, climb_to_maximum(response, idx[at]))
    widest = MAX_SPOT_SIGMA_PX / bin_px
    compact = (spots.var_row <= widest**2) & (spots.var_col <= widest**2)  # NaN: not
    n_blobs = int(blobs.max()) + 1
    loose = np.bincount(blobs[at[~compact]], minlength=n_blobs) > 0
    fitted = (np.bincount(blobs[at], minlength=n_blobs) > 0) & ~loose
    inside = np.flatnonzero(fitted[blobs])
    if len(inside) == 0:
        return CrowdedSeeds.empty()
    reach = REACH_SIGMAS * widest
    owner = blobs[at]
    rows, cols = np.divmod(idx[inside], width)
    light = spots_light(spots, owner, rows, cols, blobs[inside], width, reach)
    noise = response.ravel()[idx[inside]] / snr[inside]
    residual = np.full(len(idx), -np.inf)
    residual[inside] = snr[inside] - light / noise
    maxima = np.flatnonzero(local_maxima(pixels, residual, pixels.margin, residual >= threshold))
    centres = np.column_stack([spots.row, spots.col])
    seed_rows, seed_cols = np.divmod(idx[maxima], width)
    apart, nearest = _nearest(centres, seed_rows, seed_cols, width)
    share = residual[maxima] / snr[at[nearest]]
    # The pole rows are the filters' replicated border: a spot's tail bends there.
    inner = (seed_rows > 0) & (seed_rows < response.shape[0] - 1)
    new = maxima[(apart > max(MIN_SEPARATION_PX / bin_px, 1.0)) & (share >= MIN_SHARE) & inner]
    if len(new) == 0:
        return CrowdedSeeds.empty()
    # Each new seed's own spot: a Gaussian through the residual at its pixel and around.
    around = window_indices(response.shape, idx[new], CROSS)
    around_rows, around_cols = np.divmod(around.ravel(), width)
    around_light = spots_light(
        spots, owner, around_rows, around_cols, np.repeat(blobs[new], len(CROSS)), width, reach
    ).reshape(around.shape)
    cross = tuple((response.ravel()[around] - around_light).T.astype(np.float64))
    own = gaussian_spots(response, idx[new], cross)
    narrowest = (MIN_SPOT_SIGMA_PX / bin_px) ** 2
    spot = (own.var_row >= narrowest) & (own.var_col >= narrowest)
    return CrowdedSeeds(new[spot], residual[new[spot]], own.row[spot], own.col[spot])


def _nearest(
    centres: NDArray[np.float64],
    rows: NDArray[np.integer],
    cols: NDArray[np.integer],
    width: int,
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Distance from each pixel to the nearest centre, pixels (columns wrap at the seam),
    and that centre."""
    if len(rows) == 0:
        return np.zeros(0), np.zeros(0, np.intp)
    # A periodic box on both axes; rows get room enough never to wrap.
    height = 2.0 * (float(max(np.max(rows), np.max(centres[:, 0]))) + 2.0)
    box = [height, float(width)]

    def place(r: NDArray[np.number], c: NDArray[np.number]) -> NDArray[np.float64]:
        return np.column_stack([r, wrap_columns(c, width)]).astype(np.float64)

    tree = cKDTree(place(centres[:, 0], centres[:, 1]), boxsize=box)
    distance, nearest = tree.query(place(rows, cols))
    return np.asarray(distance, np.float64), np.asarray(nearest, np.intp)
