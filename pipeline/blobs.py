"""Blobs of candidate pixels: 8-connected labelling across the 360° seam, and measures.

Everything here touches the candidate pixels only (sparse flat indices ``v · W + u``),
never the whole frame: labelling is a sparse graph of the pixels and their forward
neighbours (`scipy.sparse.csgraph.connected_components`), measures are `np.bincount`
reductions over the labels.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields
from typing import Any, Self

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

# Neighbours after a pixel in raster order (8-connectivity): right, then the row below.
_FORWARD_NEIGHBOURS = np.array([(0, 1), (1, -1), (1, 0), (1, 1)])


@functools.cache
def _window(radius: int) -> NDArray[np.intp]:
    """Offsets ``(dr, dc)`` of a square window of half side `radius` but its centre, in
    raster order (built once per radius: every frame asks for it)."""
    offsets = np.arange(-radius, radius + 1)
    dr, dc = (a.ravel() for a in np.meshgrid(offsets, offsets, indexing="ij"))
    centre = (dr == 0) & (dc == 0)
    window = np.column_stack([dr[~centre], dc[~centre]])
    window.flags.writeable = False  # shared by every caller
    return window


@dataclass(frozen=True)
class Blobs:
    """Blobs of one frame (columns of equal length).

    Attributes
    ----------
    x, y : float64
        Centroid in pixels (``x`` wrapped into ``[0, W)``; `centroid`).
    area : intp
        Pixels in the blob.
    peak : float64
        Largest foreground in the blob, grey levels.
    peak_x, peak_y : intp
        Brightest luminance pixel of the blob (ties: the first in raster order).
    snr : float64
        Largest matched-filter response in the blob, in units of the noise σ.
    trough : float64
        Lowest matched-filter response around the blob's peak over the peak's response
        (`trough`); NaN where not measured.
    hollow : float64
        How much darker than a moment ago the darkest spot around the peak has become,
        over the peak's response (`pipeline.hollow.hollow_depth`); NaN where not measured.
    """

    x: NDArray[np.float64]
    y: NDArray[np.float64]
    area: NDArray[np.intp]
    peak: NDArray[np.float64]
    peak_x: NDArray[np.intp]
    peak_y: NDArray[np.intp]
    snr: NDArray[np.float64]
    trough: NDArray[np.float64]
    hollow: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.x)

    @classmethod
    def empty(cls) -> Self:
        integer = {"area", "peak_x", "peak_y"}
        columns: dict[str, Any] = {
            f.name: np.zeros(0, np.intp if f.name in integer else np.float64) for f in fields(cls)
        }
        return cls(**columns)

    def select(self, rows: NDArray[np.intp]) -> Self:
        return type(self)(**{f.name: getattr(self, f.name)[rows] for f in fields(self)})


class PixelIndex:
    """Where each of a frame's sparse pixels sits in their list, for neighbour queries.

    A dense image of list positions (−1: not a listed pixel), reused from frame to frame:
    a neighbour query is then one gather instead of a binary search in the list. The
    image has a margin of `margin` pixels on every side: rows beyond the poles stay −1,
    and the columns beyond the 360° seam repeat the listed pixels of the other edge, so
    a neighbour is a fixed offset from a pixel, without wrapping or bounds checks.

    Parameters
    ----------
    shape : (int, int)
        Rows ``H`` and columns ``W`` of the frame.
    margin : int
        Largest neighbour offset that will be asked for, pixels (at most ``W``).
    """

    def __init__(self, shape: tuple[int, int], margin: int) -> None:
        self.height, self.width = shape
        if not 0 <= margin <= self.width:
            raise ValueError(f"margin must be 0 .. {self.width} pixels, got {margin}")
        self.margin = margin
        self._stride = self.width + 2 * margin
        self._position = np.full((self.height + 2 * margin) * self._stride, -1, np.int32)
        self._written = np.zeros(0, np.intp)
        self._at = np.zeros(0, np.intp)

    def assign(self, idx: NDArray[np.intp]) -> None:
        """List the pixels of flat indices `idx` (``v · W + u``), replacing the last list."""
        self._position[self._written] = -1
        rows, cols = np.divmod(idx, self.width)
        m = self.margin
        self._at = (rows + m) * self._stride + cols + m
        left, right = np.flatnonzero(cols < m), np.flatnonzero(cols >= self.width - m)
        written = np.concatenate(
            [self._at, self._at[left] + self.width, self._at[right] - self.width]
        )
        order = np.concatenate([np.arange(len(idx)), left, right]).astype(np.int32)
        self._position[written] = order
        self._written = written

    def __len__(self) -> int:
        return len(self._at)

    def neighbours(
        self, offsets: NDArray[np.intp], of: NDArray[np.intp] | None = None
    ) -> NDArray[np.int32]:
        """List positions of the pixels at `offsets` from each listed pixel, or from
        those at list positions `of`; −1 where that pixel is not listed or lies beyond
        the poles.

        Parameters
        ----------
        offsets : ndarray of int, shape (K, 2)
            Row and column offsets ``(dr, dc)``, each at most `margin` pixels.
        of : ndarray of int, shape (N,), optional
            List positions of the pixels asked about (default: all of them).

        Returns
        -------
        ndarray of int32, shape (N, K)
        """
        offsets = np.asarray(offsets, np.intp).reshape(-1, 2)
        if len(offsets) and np.abs(offsets).max() > self.margin:
            raise ValueError(f"offsets {offsets.tolist()} exceed the margin of {self.margin} px")
        at = self._at if of is None else self._at[of]
        return self._position[at[:, None] + (offsets[:, 0] * self._stride + offsets[:, 1])]


def label(pixels: PixelIndex) -> NDArray[np.intp]:
    """Connected-component labels of a frame's listed pixels (8-connected, columns wrap).

    Parameters
    ----------
    pixels : PixelIndex
        The frame's pixels (`PixelIndex.assign`, ascending flat indices), margin ≥ 1.

    Returns
    -------
    ndarray of int, shape (N,)
        Labels ``0 .. n − 1`` of the listed pixels, numbered in raster order of each
        component's first pixel.
    """
    n = len(pixels)
    if n == 0:
        return np.zeros(0, np.intp)
    pos = pixels.neighbours(_FORWARD_NEIGHBOURS).ravel()
    hit = np.flatnonzero(pos >= 0)
    edges_from, edges_to = hit // len(_FORWARD_NEIGHBOURS), pos[hit]
    graph = coo_matrix((np.ones(len(edges_from), np.int8), (edges_from, edges_to)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    # connected_components numbers components by their lowest node: raster order here.
    return labels.astype(np.intp)


def local_maxima(
    pixels: PixelIndex,
    values: NDArray[np.float64],
    radius: int,
    candidates: NDArray[np.bool_],
) -> NDArray[np.bool_]:
    """Which `candidates` hold the largest value within `radius` (Chebyshev) of the pixels.

    Ties go to the first pixel in raster order, so a plateau yields one maximum.

    Parameters
    ----------
    pixels : PixelIndex
        The frame's pixels (`PixelIndex.assign`, ascending flat indices), margin ≥
        `radius`.
    values : ndarray of float, shape (N,)
        Their values.
    radius : int
        Half side of the window, pixels.
    candidates : ndarray of bool, shape (N,)
        The pixels to test (e.g. those above a seed level); only they can be maxima.
    """
    tested = np.flatnonzero(candidates)
    mine = values[tested][:, None]
    window = _window(radius)
    pos = pixels.neighbours(window, tested)
    other = values[pos]  # pos −1 reads the last value: masked by `pos >= 0`
    # Ties go to the neighbour that comes first in raster order.
    before = (window[:, 0] < 0) | ((window[:, 0] == 0) & (window[:, 1] < 0))
    beaten = (pos >= 0) & ((other > mine) | ((other == mine) & before))
    peak = ~beaten.any(axis=1)
    out = np.zeros(len(values), bool)
    out[tested[peak]] = True
    return out


def ring_max(
    image: NDArray[np.floating], idx: NDArray[np.intp], radius: int
) -> NDArray[np.float64]:
    """Largest value of `image` on the square ring `radius` pixels (Chebyshev) around
    each pixel.

    Columns wrap at the 360° seam; rows beyond the poles read the pole row.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        E.g. the matched filter's response.
    idx : ndarray of intp, shape (N,)
        Flat indices of the centre pixels.
    radius : int
        Ring radius, pixels (≥ 1): the ring holds ``8 · radius`` pixels.

    Returns
    -------
    ndarray of float64, shape (N,)
    """
    window = _window(radius)
    return np.asarray(
        _around(image, idx, window[np.abs(window).max(axis=1) == radius]).max(axis=1), np.float64
    )


def trough(image: NDArray[np.floating], idx: NDArray[np.intp], radius: int) -> NDArray[np.float64]:
    """Lowest value of `image` within `radius` pixels (Chebyshev) of each pixel, over
    the pixel's own value.

    On the matched-filtered foreground (frame − background) a light that appears from
    nothing, as a flash does, stands on a neighbourhood near 0 (noise); a light that
    moved leaves a dark hollow where the background still holds it, and a swaying edge
    is bright on one side and dark on the other: both give a trough well below 0.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        The matched filter's response, grey levels (signed).
    idx : ndarray of intp, shape (N,)
        Flat indices of the peaks (positive values).
    radius : int
        Half side of the square window, pixels (≥ 1). Columns wrap at the 360° seam;
        rows beyond the poles read the pole row.

    Returns
    -------
    ndarray of float64, shape (N,)
        At most 1; 0 for a window at the background's level, negative below it.
    """
    lowest = _around(image, idx, _window(radius)).min(axis=1)
    return np.minimum(lowest, image.ravel()[idx]).astype(np.float64) / image.ravel()[idx]


def window_indices(
    shape: tuple[int, int], idx: NDArray[np.intp], offsets: NDArray[np.intp]
) -> NDArray[np.intp]:
    """(N, K) flat indices of the pixels at `offsets` ``(dr, dc)`` from each flat index
    `idx` of an image of `shape`: columns wrap at the 360° seam, rows beyond the poles
    read the pole row."""
    height, width = shape
    rows, cols = np.divmod(idx, width)
    dr, dc = offsets.T
    return np.clip(rows[:, None] + dr, 0, height - 1) * width + (cols[:, None] + dc) % width


def _around(
    image: NDArray[np.floating], idx: NDArray[np.intp], offsets: NDArray[np.intp]
) -> NDArray[np.floating]:
    """(N, K) values of `image` at `offsets` from each flat index (`window_indices`)."""
    return image.ravel()[window_indices(image.shape, idx, offsets)]


def split_at_peaks(
    idx: NDArray[np.intp], labels: NDArray[np.intp], peaks: NDArray[np.bool_], width: int
) -> NDArray[np.intp]:
    """Blob labels after splitting each blob between its peaks (nearest peak wins).

    Pixels of blobs without a peak get -1. New labels ``0 .. n_peaks − 1`` follow the
    raster order of the peaks; a blob with one peak keeps all its pixels.
    """
    peak_rows = np.flatnonzero(peaks)
    n_blobs = int(labels.max()) + 1 if len(labels) else 0
    peaks_in_blob = np.bincount(labels[peak_rows], minlength=n_blobs)
    # Blobs with one peak keep their pixels; only the others need a nearest-peak search.
    new_label = np.full(n_blobs, -1, np.intp)
    new_label[labels[peak_rows]] = np.arange(len(peak_rows))
    out = np.where(peaks_in_blob[labels] == 1, new_label[labels], -1)
    shared = np.flatnonzero(peaks_in_blob[labels] > 1)
    if len(shared):
        rows, cols = np.divmod(idx, width)
        height = int(rows.max()) + 1
        # Blob label as a third coordinate, far apart: pixels find their own blob's peaks.
        spread = float(2 * (height + width))
        points = np.column_stack([rows, cols, labels * spread]).astype(np.float64)
        box = [2.0 * spread, width, (n_blobs + 1) * spread]
        contested = peak_rows[peaks_in_blob[labels[peak_rows]] > 1]
        tree = cKDTree(points[contested], boxsize=box)
        _, nearest = tree.query(points[shared], k=1)
        out[shared] = np.searchsorted(peak_rows, contested[nearest])
    return out


def upsample(
    idx: NDArray[np.intp], labels: NDArray[np.intp], width: int, bin_px: int
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Full-resolution pixels (ascending) and labels of pixels of a ``bin_px``-binned image.

    ``width`` is the binned image's width. Blob numbering (raster order of the first
    pixel) is preserved.
    """
    if bin_px == 1:
        return idx, labels
    rows, cols = np.divmod(idx, width)
    offsets = np.arange(bin_px)
    full_rows = (rows[:, None, None] * bin_px + offsets[None, :, None]).repeat(bin_px, axis=2)
    full_cols = (cols[:, None, None] * bin_px + offsets[None, None, :]).repeat(bin_px, axis=1)
    full = (full_rows * width * bin_px + full_cols).ravel()
    order = np.argsort(full, kind="stable")
    return full[order], np.repeat(labels, bin_px * bin_px)[order]


def _gaussian_through(
    before: NDArray[np.float64], centre: NDArray[np.float64], after: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Vertex offset (within ±0.5 pixel) and variance (pixels²) of the Gaussian through
    three values one pixel apart (a parabola through their logarithms).

    Where a value is not positive (a dark edge beside a spot) the parabola goes through
    the values themselves and the variance is NaN; so it is where they do not curve down.
    """
    positive = (before > 0) & (after > 0) & (centre > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        lb, lc, la = (np.log(np.where(positive, v, 1.0)) for v in (before, centre, after))
        b, c, a = (np.where(positive, lv, v) for lv, v in ((lb, before), (lc, centre), (la, after)))
        curvature = b - 2 * c + a
        step = 0.5 * (b - a) / curvature
        variance = np.where(positive & (curvature < 0), -1.0 / curvature, np.nan)
    return np.where(np.isfinite(step), np.clip(step, -0.5, 0.5), 0.0), variance


#: Offsets ``(dr, dc)`` of a pixel and its four neighbours: at, left, right, above, below.
CROSS = np.array([(0, 0), (0, -1), (0, 1), (-1, 0), (1, 0)])


def wrap_columns(col: NDArray[np.number], width: int) -> NDArray[np.float64]:
    """Columns wrapped into ``[0, width)`` at the 360° seam."""
    wrapped = np.mod(np.asarray(col, np.float64), width)
    wrapped[wrapped >= width] -= width  # mod can round a tiny negative up to exactly W
    return wrapped


def to_full_resolution(
    row: NDArray[np.float64], col: NDArray[np.float64], width: int, bin_px: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Sub-pixel positions in a ``bin_px``-binned image of `width` bins as ``(x, y)`` in
    full-resolution pixels, ``x`` wrapped into ``[0, bin_px · width)``."""
    return wrap_columns((col + 0.5) * bin_px - 0.5, width * bin_px), (row + 0.5) * bin_px - 0.5


def subpixel_peak(
    image: NDArray[np.float32], peak: NDArray[np.intp], bin_px: int = 1
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Sub-pixel position of the maxima of a smooth, Gaussian-like image near `peak`.

    A Gaussian through the maximum and its two neighbours along each axis (the
    logarithm of the values is a parabola): exact for a Gaussian spot whatever its
    position in the pixel, so it has no pixel-locking bias, and it reads the matched
    filter's output, which has already integrated the whole spot.

    The peaks come from the SNR, which divides the response by a noise level that
    steps across a bright edge (the sky behind leaves), so a peak can sit a pixel off
    the response's own maximum; each is first moved uphill on `image` (at most
    `CLIMB_STEPS` pixels, kept only when it reaches a maximum of its 3 × 3
    neighbourhood). Where a neighbour is not positive (a dark edge beside the spot) the
    parabola goes through the values themselves.

    Parameters
    ----------
    image : ndarray of float32, shape (H, W)
        The matched-filter response (columns wrap at the 360° seam).
    peak : ndarray of int, shape (n,)
        Flat indices ``v · W + u`` of local maxima of the SNR.
    bin_px : int
        Bin side of `image`: its pixel ``(i, j)`` covers full-resolution pixels
        ``b·i .. b·i + b − 1``.

    Returns
    -------
    x, y : ndarray of float, shape (n,)
        Positions in full-resolution pixels, ``x`` wrapped into ``[0, b · W)``; offsets
        from the (moved) peak pixel are within ±0.5 pixel of `image`.
    """
    spots = gaussian_spots(image, climb_to_maximum(image, np.asarray(peak, np.intp)))
    return to_full_resolution(spots.row, spots.col, image.shape[1], bin_px)


@dataclass(frozen=True)
class Spots:
    """Gaussian spots fitted at peaks of an image (`gaussian_spots`), in its pixels.

    Attributes
    ----------
    row, col : ndarray of float64
        Sub-pixel centre (``col`` may lie half a pixel beyond the seam).
    var_row, var_col : ndarray of float64
        Variance along each axis, pixels²; NaN where the values do not fall off as a
        Gaussian's (`_gaussian_through`).
    amplitude : ndarray of float64
        Height at the centre.
    """

    row: NDArray[np.float64]
    col: NDArray[np.float64]
    var_row: NDArray[np.float64]
    var_col: NDArray[np.float64]
    amplitude: NDArray[np.float64]


def gaussian_spots(
    image: NDArray[np.floating],
    peak: NDArray[np.intp],
    cross: tuple[NDArray[np.float64], ...] | None = None,
) -> Spots:
    """A separable Gaussian through each peak pixel of `image` and its four neighbours.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        E.g. the matched filter's response (columns wrap at the 360° seam; rows at the
        poles keep their row).
    peak : ndarray of int, shape (n,)
        Flat indices of the spots' brightest pixels.
    cross : tuple of 5 ndarrays, optional
        The values to fit instead of `image`'s: at, left of, right of, above and below
        each peak (e.g. `image` less the light of other spots).
    """
    height, width = image.shape
    peak = np.asarray(peak, np.intp)
    rows, cols = np.divmod(peak, width)
    if cross is None:
        cross = tuple(_around(image, peak, CROSS).astype(np.float64).T)
    centre, left, right, up, down = cross
    dx, var_col = _gaussian_through(left, centre, right)
    dy, var_row = _gaussian_through(up, centre, down)
    at_pole = (rows == 0) | (rows == height - 1)
    dy, var_row = np.where(at_pole, 0.0, dy), np.where(at_pole, np.nan, var_row)
    # The fitted height at the vertex, from the peak pixel's value (a NaN term adds 0).
    with np.errstate(invalid="ignore", divide="ignore"):
        lift = np.nan_to_num(dx**2 / (2 * var_col)) + np.nan_to_num(dy**2 / (2 * var_row))
    return Spots(rows + dy, cols + dx, var_row, var_col, centre * np.exp(lift))


def spots_light(
    spots: Spots,
    spot_blob: NDArray[np.intp],
    rows: NDArray[np.floating],
    cols: NDArray[np.floating],
    blob: NDArray[np.intp],
    width: int,
    radius: float,
) -> NDArray[np.float64]:
    """The light the Gaussian `spots` of a blob put at points of the same blob.

    Parameters
    ----------
    spots : Spots
        Spots with a variance on both axes.
    spot_blob : ndarray of int, shape (n,)
        The blob of each spot.
    rows, cols : ndarray, shape (m,)
        The points, image pixels.
    blob : ndarray of int, shape (m,)
        The blob of each point.
    width : int
        Image width: columns wrap at the 360° seam.
    radius : float
        Farthest a spot reaches, pixels.

    Returns
    -------
    ndarray of float64, shape (m,)
        The sum of the spots' values at each point.
    """
    out = np.zeros(len(rows))
    if len(spots.row) == 0 or len(rows) == 0:
        return out
    # Blob as a third coordinate, far apart: points meet only their own blob's spots.
    # The box is periodic on every axis, so rows and blobs get room to never wrap.
    extent = float(max(np.max(rows), np.max(spots.row))) + radius + 2.0
    n_blobs = int(max(np.max(blob), np.max(spot_blob))) + 1
    box = [2.0 * extent, float(width), (n_blobs + 1) * 2.0 * extent]

    def place(
        r: NDArray[np.floating], c: NDArray[np.floating], b: NDArray[np.intp]
    ) -> NDArray[np.float64]:
        return np.column_stack([r, wrap_columns(c, width), b * 2.0 * extent]).astype(np.float64)

    pairs = cKDTree(place(spots.row, spots.col, spot_blob), boxsize=box).sparse_distance_matrix(
        cKDTree(place(rows, cols, blob), boxsize=box), radius, output_type="ndarray"
    )
    i, j = pairs["i"], pairs["j"]
    dr = rows[j] - spots.row[i]
    dc = (cols[j] - spots.col[i] + width / 2) % width - width / 2
    light = spots.amplitude[i] * np.exp(
        -(dr**2) / (2 * spots.var_row[i]) - dc**2 / (2 * spots.var_col[i])
    )
    np.add.at(out, j, light)
    return out


#: Pixels a peak may move uphill on the response to reach its maximum (`subpixel_peak`).
CLIMB_STEPS = 2


def climb_to_maximum(image: NDArray[np.floating], peak: NDArray[np.intp]) -> NDArray[np.intp]:
    """Each peak moved to its largest 3 × 3 neighbour while that is larger, at most
    `CLIMB_STEPS` times; a peak that has not then reached a maximum stays where it was
    (a flash on the slope of a glow must not be walked into the glow)."""
    flat, window, each = image.ravel(), _window(1), np.arange(len(peak))
    at = peak
    for _ in range(CLIMB_STEPS):
        around = window_indices(image.shape, at, window)
        best = around[each, flat[around].argmax(axis=1)]
        at = np.where(flat[best] > flat[at], best, at)
    top = flat[at] >= _around(image, at, window).max(axis=1, initial=-np.inf)
    return np.where(top, at, peak)


def measure(
    idx: NDArray[np.intp],
    labels: NDArray[np.intp],
    foreground: NDArray[np.floating],
    luma: NDArray[np.uint8],
    snr: NDArray[np.float64],
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    troughs: NDArray[np.float64],
    hollows: NDArray[np.float64],
) -> Blobs:
    """Measure labelled blobs of one frame at full resolution.

    Parameters
    ----------
    idx : ndarray of int, shape (N,)
        Ascending flat indices ``v · W + u`` of the blobs' pixels.
    labels : ndarray of int, shape (N,)
        Their blob labels ``0 .. n − 1``.
    foreground : ndarray of float, shape (N,)
        Frame minus background at those pixels, grey levels.
    luma : ndarray of uint8, shape (H, W)
        The frame's luminance, for the brightest pixel.
    snr : ndarray of float, shape (n,)
        Each blob's largest filtered response in units of σ (passed through).
    x, y : ndarray of float, shape (n,)
        Each blob's centroid (`centroid`), pixels (passed through).
    troughs, hollows : ndarray of float, shape (n,)
        Each blob's `trough` and hollow depth (passed through).

    Returns
    -------
    Blobs
        One row per label, in label order; ``peak`` is the largest foreground (clipped
        at 0), ``peak_x``/``peak_y`` the brightest luminance pixel (ties: the first in
        raster order), ``area`` the pixel count.
    """
    if len(idx) == 0:
        return Blobs.empty()
    width = luma.shape[1]
    rows, cols = np.divmod(idx, width)
    values = np.maximum(np.asarray(foreground, np.float64), 0.0)
    order = np.lexsort((idx, -luma[rows, cols].astype(np.int16), labels))
    starts = np.flatnonzero(np.r_[True, np.diff(labels[order]) != 0])
    return Blobs(
        x=x,
        y=y,
        area=np.bincount(labels),
        peak=np.maximum.reduceat(values[order], starts),
        peak_x=cols[order[starts]],
        peak_y=rows[order[starts]],
        snr=snr,
        trough=troughs,
        hollow=hollows,
    )
