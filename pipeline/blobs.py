"""Blobs of candidate pixels: 8-connected labelling across the 360° seam, and measures.

Everything here touches the candidate pixels only (sparse flat indices ``v · W + u``),
never the whole frame: labelling is a sparse graph of the pixels and their forward
neighbours (`scipy.sparse.csgraph.connected_components`), measures are `np.bincount`
reductions over the labels.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Self

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

# Neighbours after a pixel in raster order (8-connectivity): right, then the row below.
_FORWARD_NEIGHBOURS = ((0, 1), (1, -1), (1, 0), (1, 1))


@dataclass(frozen=True)
class Blobs:
    """Blobs of one frame (columns of equal length).

    Attributes
    ----------
    x, y : float64
        Foreground-weighted centroid in pixels (``x`` wrapped into ``[0, W)``).
    area : intp
        Pixels in the blob.
    peak : float64
        Largest foreground in the blob, grey levels.
    peak_x, peak_y : intp
        Brightest luminance pixel of the blob (ties: the first in raster order).
    snr : float64
        Largest matched-filter response in the blob, in units of the noise σ.
    """

    x: NDArray[np.float64]
    y: NDArray[np.float64]
    area: NDArray[np.intp]
    peak: NDArray[np.float64]
    peak_x: NDArray[np.intp]
    peak_y: NDArray[np.intp]
    snr: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.x)

    @classmethod
    def empty(cls) -> Self:
        none_f, none_i = np.zeros(0), np.zeros(0, np.intp)
        return cls(
            x=none_f, y=none_f, area=none_i, peak=none_f, peak_x=none_i, peak_y=none_i, snr=none_f
        )

    def select(self, rows: NDArray[np.intp]) -> Self:
        return type(self)(**{f.name: getattr(self, f.name)[rows] for f in fields(self)})


def label(idx: NDArray[np.intp], width: int) -> NDArray[np.intp]:
    """Connected-component labels of sparse pixels (8-connected, columns wrap).

    Parameters
    ----------
    idx : ndarray of int, shape (N,)
        Ascending flat indices ``v · W + u``.
    width : int
        Image width ``W`` in pixels.

    Returns
    -------
    ndarray of int, shape (N,)
        Labels ``0 .. n − 1``, numbered in raster order of each component's first pixel.
    """
    if len(idx) == 0:
        return np.zeros(0, np.intp)
    rows, cols = np.divmod(idx, width)
    src, dst = [], []
    for dr, dc in _FORWARD_NEIGHBOURS:
        neighbour = (rows + dr) * width + (cols + dc) % width
        pos = np.searchsorted(idx, neighbour)
        pos[pos == len(idx)] = 0
        hit = idx[pos] == neighbour
        src.append(np.flatnonzero(hit))
        dst.append(pos[hit])
    edges_from, edges_to = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix(
        (np.ones(len(edges_from), np.int8), (edges_from, edges_to)), shape=(len(idx), len(idx))
    )
    _, labels = connected_components(graph, directed=False)
    # connected_components numbers components by their lowest node: raster order here.
    return labels.astype(np.intp)


def _neighbours(
    idx: NDArray[np.intp], width: int, dr: int, dc: int
) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """Position in `idx` of each pixel's neighbour at offset (dr, dc), and whether it is there."""
    rows, cols = np.divmod(idx, width)
    neighbour = (rows + dr) * width + (cols + dc) % width
    pos = np.minimum(np.searchsorted(idx, neighbour), len(idx) - 1)
    return pos, idx[pos] == neighbour


def local_maxima(
    idx: NDArray[np.intp], values: NDArray[np.float64], width: int, radius: int
) -> NDArray[np.bool_]:
    """Pixels whose value is the largest within `radius` (Chebyshev) among the pixels given.

    Ties go to the first pixel in raster order, so a plateau yields one maximum.

    Parameters
    ----------
    idx : ndarray of int, shape (N,)
        Ascending flat indices ``v · W + u`` (columns wrap at the 360° seam).
    values : ndarray of float, shape (N,)
        Their values.
    width : int
        Image width ``W``.
    radius : int
        Half side of the window, pixels.
    """
    peak = np.ones(len(idx), bool)
    for dr in range(-radius, radius + 1):
        for dc in range(-radius, radius + 1):
            if dr == 0 and dc == 0:
                continue
            pos, present = _neighbours(idx, width, dr, dc)
            before = (dr, dc) < (0, 0)  # the neighbour comes first in raster order
            other = values[pos]
            beaten = present & ((other > values) | ((other == values) & before))
            peak &= ~beaten
    return peak


def split_at_peaks(
    idx: NDArray[np.intp], labels: NDArray[np.intp], peaks: NDArray[np.bool_], width: int
) -> NDArray[np.intp]:
    """Blob labels after splitting each blob between its peaks (nearest peak wins).

    Pixels of blobs without a peak get -1. New labels ``0 .. n_peaks − 1`` follow the
    raster order of the peaks; a blob with one peak keeps all its pixels.
    """
    out = np.full(len(idx), -1, np.intp)
    peak_rows = np.flatnonzero(peaks)
    if len(peak_rows) == 0:
        return out
    rows, cols = np.divmod(idx, width)
    height = int(rows.max()) + 1
    # Blob label as a third coordinate, far apart: a pixel only finds its own blob's peaks.
    spread = float(2 * (height + width))
    points = np.column_stack([rows, cols, labels * spread]).astype(np.float64)
    tree = cKDTree(points[peak_rows], boxsize=[2.0 * spread, width, (labels.max() + 2) * spread])
    distance, nearest = tree.query(points, k=1)
    mine = distance < spread / 2
    out[mine] = nearest[mine]
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


def centroid(
    idx: NDArray[np.intp],
    labels: NDArray[np.intp],
    weights: NDArray[np.float64],
    width: int,
    bin_px: int = 1,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Weighted centroid of each blob, in full-resolution pixels.

    Parameters
    ----------
    idx : ndarray of int, shape (N,)
        Flat indices ``v · W + u`` of the blobs' pixels on a grid binned by `bin_px`.
    labels : ndarray of int, shape (N,)
        Their blob labels ``0 .. n − 1``.
    weights : ndarray of float, shape (N,)
        Non-negative weights: the matched-filter response above the extent level, which
        falls to zero at the blob's edge, so that the cut does not pull the centroid
        toward a pixel centre.
    width : int
        Width ``W`` of the (binned) grid, pixels.
    bin_px : int
        Bin side: bin ``(i, j)`` covers full-resolution pixels ``b·i .. b·i + b − 1``.

    Returns
    -------
    x, y : ndarray of float, shape (n,)
        Centroids in full-resolution pixels, ``x`` wrapped into ``[0, b · W)``.
    """
    rows, cols = np.divmod(idx, width)
    n = int(labels.max()) + 1 if len(labels) else 0
    anchor = np.zeros(n, np.intp)
    anchor[labels[::-1]] = cols[::-1]  # the first pixel of each blob
    # Offsets from the anchor, wrapped, so a blob across the seam stays whole.
    du = (cols - anchor[labels] + width // 2) % width - width // 2
    total = np.maximum(np.bincount(labels, weights=weights, minlength=n), 1e-12)
    x = np.mod(anchor + np.bincount(labels, weights=weights * du, minlength=n) / total, width)
    y = np.bincount(labels, weights=weights * rows, minlength=n) / total
    full_width = width * bin_px
    x = np.mod((x + 0.5) * bin_px - 0.5, full_width)
    x[x >= full_width] -= full_width  # mod can round a tiny negative up to exactly W
    return x, (y + 0.5) * bin_px - 0.5


def measure(
    idx: NDArray[np.intp],
    labels: NDArray[np.intp],
    foreground: NDArray[np.float32],
    luma: NDArray[np.uint8],
    snr: NDArray[np.float64],
    ring_radius: int,
) -> Blobs:
    """Measure labelled blobs of one frame.

    The centroid weights the clipped foreground over the blob dilated by `ring_radius`
    pixels: the thresholded pixels alone are an asymmetric cut of the spot and bias
    the centroid toward the nearest pixel centre (by up to 0.23 px for a σ = 1 px spot;
    under 0.06 px with a one-pixel ring).

    Parameters
    ----------
    idx : ndarray of int, shape (N,)
        Ascending flat indices ``v · W + u`` of the blobs' pixels.
    labels : ndarray of int, shape (N,)
        Their blob labels (`label`).
    foreground : ndarray of float32, shape (H, W)
        Frame minus background, grey levels.
    luma : ndarray of uint8, shape (H, W)
        The frame's luminance, for the brightest pixel.
    snr : ndarray of float, shape (n_blobs,)
        Each blob's largest filtered response in units of σ (passed through).
    ring_radius : int
        Dilation of the centroid window around each blob, in pixels.

    Returns
    -------
    Blobs
        One row per label, in label order.
    """
    if len(idx) == 0:
        return Blobs.empty()
    height, width = luma.shape
    rows, cols = np.divmod(idx, width)
    values = np.maximum(foreground[rows, cols].astype(np.float64), 0.0)
    order = np.lexsort((idx, -luma[rows, cols].astype(np.int16), labels))
    starts = np.flatnonzero(np.r_[True, np.diff(labels[order]) != 0])
    peak_x, peak_y = cols[order[starts]], rows[order[starts]]
    peak = np.maximum.reduceat(values[order], starts)
    area = np.bincount(labels)

    ring, ring_labels = _ring(idx, labels, width, height, ring_radius)
    ring_rows, ring_cols = np.divmod(ring, width)
    all_labels = np.concatenate([labels, ring_labels])
    weight = np.concatenate([values, np.maximum(foreground[ring_rows, ring_cols], 0.0)])
    all_rows = np.concatenate([rows, ring_rows])
    all_cols = np.concatenate([cols, ring_cols])
    # Offsets from the brightest pixel, wrapped, so a blob across the seam stays whole.
    du = (all_cols - peak_x[all_labels] + width // 2) % width - width // 2
    # A blob of zero foreground (possible only at the noise floor) keeps its peak pixel.
    total = np.maximum(np.bincount(all_labels, weights=weight), 1e-12)
    x = np.mod(peak_x + np.bincount(all_labels, weights=weight * du) / total, width)
    x[x >= width] -= width  # mod can round a tiny negative up to exactly W
    y = np.bincount(all_labels, weights=weight * all_rows) / total
    y = np.where(total > 1e-12, y, peak_y)
    return Blobs(x=x, y=y, area=area, peak=peak, peak_x=peak_x, peak_y=peak_y, snr=snr)


def _ring(
    idx: NDArray[np.intp], labels: NDArray[np.intp], width: int, height: int, radius: int
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Pixels within `radius` (chessboard distance) of the blobs but not in them, each
    with the label of one blob it touches."""
    rows, cols = np.divmod(idx, width)
    offsets = np.arange(-radius, radius + 1)
    dr, dc = (g.ravel()[None, :] for g in np.meshgrid(offsets, offsets, indexing="ij"))
    nr = rows[:, None] + dr
    inside = (nr >= 0) & (nr < height)
    neighbour = (nr * width + (cols[:, None] + dc) % width)[inside]
    neighbour_labels = np.broadcast_to(labels[:, None], nr.shape)[inside]
    pos = np.minimum(np.searchsorted(idx, neighbour), len(idx) - 1)
    outside = idx[pos] != neighbour
    ring, first = np.unique(neighbour[outside], return_index=True)
    return ring, neighbour_labels[outside][first]
