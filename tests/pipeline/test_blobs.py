"""Sparse-pixel blobs: the neighbour index, labelling, local maxima and rings (pipeline.blobs)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.blobs import PixelIndex, label, local_maxima, ring_max, subpixel_peak, trough


def index_of(mask: np.ndarray, margin: int) -> tuple[PixelIndex, np.ndarray]:
    idx = np.flatnonzero(mask)
    pixels = PixelIndex(mask.shape, margin)
    pixels.assign(idx)
    return pixels, idx


def test_neighbours_wrap_at_the_seam_and_stop_at_the_poles() -> None:
    mask = np.zeros((4, 6), bool)
    mask[0, 0] = mask[0, 5] = mask[1, 4] = mask[3, 1] = True
    pixels, idx = index_of(mask, margin=2)
    at = {int(i): n for n, i in enumerate(idx)}  # flat index -> list position
    offsets = np.array([(0, -1), (0, 1), (1, -2), (-1, 0), (1, 0)])
    pos = pixels.neighbours(offsets)
    assert pos.shape == (4, 5)
    assert pos[at[0], 0] == at[5]  # (0, 0) sees (0, 5) across the seam
    assert pos[at[5], 1] == at[0]
    assert pos[at[0], 2] == at[6 + 4]  # two columns back, one row down
    assert pos[at[0], 3] == -1  # beyond the top pole
    assert pos[at[3 * 6 + 1], 4] == -1  # beyond the bottom pole
    of = np.array([at[3 * 6 + 1], at[0]])
    np.testing.assert_array_equal(pixels.neighbours(offsets, of), pos[of])
    assert pixels.neighbours(offsets[1:2], of)[0, 0] == -1  # nothing right of (3, 1)


def test_a_new_list_clears_the_last_one() -> None:
    pixels = PixelIndex((3, 5), margin=1)
    pixels.assign(np.array([0, 4, 7]))  # (0, 0), (0, 4) and (1, 2)
    pixels.assign(np.array([8]))  # (1, 3)
    assert len(pixels) == 1
    assert pixels.neighbours(np.array([(0, -1)]))[0, 0] == -1  # (1, 2) is no longer listed
    pixels.assign(np.array([2, 3]))
    np.testing.assert_array_equal(pixels.neighbours(np.array([(0, 1)])), [[1], [-1]])


def test_offsets_beyond_the_margin_are_refused() -> None:
    pixels = PixelIndex((4, 8), margin=1)
    pixels.assign(np.array([9]))
    with pytest.raises(ValueError, match="margin"):
        pixels.neighbours(np.array([(0, 1), (2, 0)]))
    with pytest.raises(ValueError, match="margin"):
        PixelIndex((4, 8), margin=9)


def test_labels_join_across_the_seam_in_raster_order() -> None:
    mask = np.zeros((5, 8), bool)
    mask[1, 7] = mask[2, 0] = True  # diagonal neighbours across the seam
    mask[3, 3:5] = True
    mask[0, 2] = True
    pixels, idx = index_of(mask, margin=1)
    labels = label(pixels)
    by_pixel = dict(zip(idx.tolist(), labels.tolist(), strict=True))
    assert by_pixel[1 * 8 + 7] == by_pixel[2 * 8 + 0]
    assert by_pixel[3 * 8 + 3] == by_pixel[3 * 8 + 4]
    assert len(set(labels.tolist())) == 3
    assert by_pixel[2] == 0  # the component with the first pixel in raster order


def test_local_maxima_within_the_radius_ties_to_the_first_pixel() -> None:
    image = np.zeros((5, 10))
    image[2, 4], image[2, 6] = 5.0, 7.0  # two apart: one maximum within radius 2
    image[0, 9], image[0, 0] = 4.0, 4.0  # a plateau across the seam: one maximum, on its left
    mask = image > 0
    pixels, idx = index_of(mask, margin=2)
    values = image.ravel()[idx]
    peaks = idx[local_maxima(pixels, values, 2, np.ones(len(idx), bool))]
    np.testing.assert_array_equal(peaks, [9, 2 * 10 + 6])
    only_first = np.asarray(idx == 2 * 10 + 4)  # only tested pixels can be maxima
    assert not local_maxima(pixels, values, 2, only_first).any()


def test_the_ring_wraps_at_the_seam_and_reads_the_pole_row_beyond_it() -> None:
    image = np.zeros((6, 10))
    image[3, 8] = 5.0  # on the ring of (3, 1) at radius 3, across the seam
    image[3, 4] = 9.0  # on the same ring, on the other side
    image[0, 2] = 2.0  # beyond the top pole from (1, 2) at radius 2: read as row 0
    centre = np.array([3 * 10 + 1, 1 * 10 + 2])
    np.testing.assert_array_equal(ring_max(image, centre, 3), [9.0, 2.0])
    image[3, 4] = 0.0
    assert ring_max(image, centre[:1], 3)[0] == 5.0
    assert ring_max(image, centre[:1], 2)[0] == 0.0  # radius 2 misses both
    assert ring_max(image, np.zeros(0, np.intp), 3).shape == (0,)


def test_the_trough_is_the_lowest_value_around_a_peak_over_the_peak() -> None:
    image = np.zeros((6, 10))
    image[3, 1] = image[1, 5] = 8.0
    image[3, 9] = -4.0  # two columns from (3, 1) across the seam
    image[0, 6] = -2.0  # beyond the top pole from (1, 5) at radius 2: read as row 0
    peaks = np.array([3 * 10 + 1, 1 * 10 + 5])
    np.testing.assert_allclose(trough(image, peaks, 2), [-0.5, -0.25])
    assert trough(image, peaks[:1], 1)[0] == 0.0  # radius 1 misses the hollow
    image[3, 2] = 9.0  # a brighter neighbour does not raise it above the peak's own value
    assert trough(image, peaks[:1], 1)[0] == 0.0
    image[:] = 3.0  # a window all as bright as the peak: 1
    assert trough(image, peaks[:1], 2)[0] == 1.0
    assert trough(image, np.zeros(0, np.intp), 2).shape == (0,)


def gaussian_spot(shape: tuple[int, int], x0: float, y0: float, sigma: float = 1.2) -> np.ndarray:
    rows, cols = np.mgrid[: shape[0], : shape[1]]
    dx = (cols - x0 + shape[1] / 2) % shape[1] - shape[1] / 2  # wraps at the seam
    return np.exp(-(dx**2 + (rows - y0) ** 2) / (2 * sigma**2)).astype(np.float32)


def test_subpixel_peak_is_exact_for_a_gaussian_at_or_beside_the_given_pixel() -> None:
    image = 40 * gaussian_spot((20, 30), 29.3, 9.8)  # across the seam
    at = np.array([10 * 30 + 29, 9 * 30 + 0, 11 * 30 + 28])  # the maximum, 1 px off, 2 px off
    x, y = subpixel_peak(image, at)
    np.testing.assert_allclose(x, 29.3, atol=1e-3)
    np.testing.assert_allclose(y, 9.8, atol=1e-3)


def test_subpixel_peak_beside_a_dark_edge_is_fitted_not_left_on_the_pixel() -> None:
    # A swaying edge leaves the foreground negative just beside the flash: the log of
    # the values cannot be taken there, the parabola through them still can.
    image = 40 * gaussian_spot((20, 30), 15.3, 9.7)
    image[9, :] -= 60 * gaussian_spot((20, 30), 15.3, 9.7)[9, :] + 5
    x, y = subpixel_peak(image, np.array([10 * 30 + 15]))
    assert abs(x[0] - 15.3) < 0.01
    assert y[0] != 10.0 and abs(y[0] - 10.0) <= 0.5


def test_subpixel_peak_on_a_slope_is_not_walked_into_the_glow() -> None:
    # A flash on the flank of a much brighter light: the response rises all the way to
    # the light, so the peak stays where the SNR put it.
    glow = 500 * gaussian_spot((40, 60), 10.0, 20.0, sigma=6.0)
    x, y = subpixel_peak(glow, np.array([20 * 60 + 22]))
    assert abs(x[0] - 22.0) <= 0.5
    assert y[0] == 20.0
