"""Rasterising primitives: anti-aliased Gaussian spots and soft discs, drawn only in small
windows around each primitive, with columns wrapping around the equirectangular seam.

Pixel convention of `pipeline.geometry`: the centre of pixel column ``i`` is ``u = i``,
so pixel ``i`` covers ``[i − ½, i + ½)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import erf

from pipeline.geometry import FloatArray

#: Luma weights of the encoder's RGB -> Y conversion (BT.601, swscale's default).
LUMA = np.array([0.299, 0.587, 0.114])


def unit_luma(rgb: ArrayLike) -> FloatArray:
    """Scale colours (..., 3) to unit BT.601 luma."""
    colour = np.asarray(rgb, dtype=np.float64)
    return colour / (colour @ LUMA)[..., None]


#: Firefly colour (yellow-green, ~560 nm after the camera's white balance), unit luma.
FIREFLY_RGB = unit_luma([0.8, 1.0, 0.25])
#: The other end of the flash colours: nearly white, as bright flashes look after the
#: camera's tone curve (real GoPro flash peaks: R/G ≈ 1.0, B/G 0.75–1.0).
WHITE_FLASH_RGB = unit_luma([1.0, 1.0, 0.85])
#: Windows reach this many standard deviations from a spot's centre.
WINDOW_SIGMAS = 3.5
#: Distance at which a typical flash has ``flash_brightness`` peak luma, metres.
REFERENCE_RANGE_M = 5.0
#: Exponent of the camera's tone curve (display gamma ~1/2.2) on linear light.
TONE_GAMMA = 0.5


def apparent_size(
    size_m: ArrayLike, distance_m: FloatArray, v: FloatArray, width: int
) -> tuple[FloatArray, FloatArray]:
    """Vertical size in pixels of objects of ``size_m`` metres at ``distance_m``, and
    the horizontal stretch ``1 / sin φ`` of the equirectangular projection at row ``v``
    (capped at 10 near the poles)."""
    height = width // 2
    stretch = 1.0 / np.maximum(np.sin(np.pi * np.asarray(v) / height), 0.1)
    return np.asarray(size_m) / distance_m / (2 * np.pi / width), stretch


def spot_sigma(range_m: FloatArray) -> FloatArray:
    """Point-spread σ in pixels of a point light at ``range_m`` metres.

    0.6–1.5 px: lens blur plus a little blooming that grows as the source gets
    closer (and brighter).
    """
    return np.clip(0.6 + 1.6 / range_m, 0.6, 1.5)


def spot_peak(intensity: FloatArray, range_m: FloatArray, brightness: float) -> FloatArray:
    """Peak luma (0–255 scale, before saturation) of a flash of relative ``intensity``.

    Received light falls as ``1 / r²``; the camera's tone curve compresses it with
    exponent ``TONE_GAMMA``. ``brightness`` is the peak of a typical flash
    (``intensity = 1``) at ``REFERENCE_RANGE_M``.
    """
    return brightness * (intensity * (REFERENCE_RANGE_M / range_m) ** 2) ** TONE_GAMMA


def flash_colour(whiteness: FloatArray) -> FloatArray:
    """Unit-luma RGB (n, 3) of flashes: ``FIREFLY_RGB`` at whiteness 0 (exactly),
    ``WHITE_FLASH_RGB`` at 1, mixed linearly in between."""
    w = np.asarray(whiteness, dtype=np.float64)[:, None]
    mixed = unit_luma((1.0 - w) * FIREFLY_RGB + w * WHITE_FLASH_RGB)
    return np.where(w == 0.0, FIREFLY_RGB, mixed)


def _pixel_integrals(
    centre: FloatArray, sigma: FloatArray, half: int
) -> tuple[NDArray, FloatArray]:
    """Pixel indices and pixel-integrated unit-peak Gaussians along one axis.

    Returns ``index`` (n, 2 half + 1) and ``weight``: the integral over each pixel of
    ``exp(−(x − centre)² / 2σ²)``, so that the weights' intensity-weighted mean is
    ``centre`` to within ``exp(−2π²σ²)`` (aliasing of the pixel grid).
    """
    index = np.floor(centre + 0.5).astype(np.int64)[:, None] + np.arange(-half, half + 1)
    scale = (np.sqrt(2.0) * sigma)[:, None]
    lower = erf((index - 0.5 - centre[:, None]) / scale)
    upper = erf((index + 0.5 - centre[:, None]) / scale)
    return index, 0.5 * (upper - lower) * np.sqrt(2.0 * np.pi) * sigma[:, None]


def _window_index(rows: NDArray, cols: NDArray, shape: tuple[int, int]) -> tuple[NDArray, NDArray]:
    """Flat pixel indices of the windows (n, K, K) and a mask of rows inside the image."""
    height, width = shape
    inside = (rows >= 0) & (rows < height)
    flat = np.clip(rows, 0, height - 1)[:, :, None] * width + np.mod(cols, width)[:, None, :]
    return flat, np.broadcast_to(inside[:, :, None], flat.shape)


def add_spots(
    image: NDArray[np.float32],
    u: FloatArray,
    v: FloatArray,
    sigma: FloatArray,
    rgb: FloatArray,
) -> None:
    """Add anti-aliased Gaussian spots to an ``(H, W, 3)`` image in place.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3), float32
        Linear 0–255 scale; not clipped here.
    u, v : ndarray, shape (n,)
        Spot centres in pixels; ``u`` wraps across the seam, rows outside the image
        are dropped.
    sigma : ndarray, shape (n,)
        Gaussian standard deviations in pixels.
    rgb : ndarray, shape (n, 3)
        Peak value per channel of each spot.
    """
    if len(u) == 0:
        return
    half = int(np.ceil(WINDOW_SIGMAS * np.max(sigma)))
    rows, wy = _pixel_integrals(np.asarray(v, dtype=np.float64), sigma, half)
    cols, wx = _pixel_integrals(np.asarray(u, dtype=np.float64), sigma, half)
    flat, inside = _window_index(rows, cols, image.shape[:2])
    weight = np.where(inside, wy[:, :, None] * wx[:, None, :], 0.0)
    values = weight[..., None] * np.asarray(rgb)[:, None, None, :]
    np.add.at(image.reshape(-1, 3), flat.ravel(), values.reshape(-1, 3).astype(np.float32))


def disc_coverage(
    u: FloatArray,
    v: FloatArray,
    radius: FloatArray,
    stretch: FloatArray,
    shape: tuple[int, int],
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """Pixels covered by soft-edged discs (silhouettes) and the covered fraction.

    Parameters
    ----------
    u, v : ndarray, shape (n,)
        Disc centres in pixels (``u`` wraps).
    radius : ndarray, shape (n,)
        Vertical radius in pixels.
    stretch : ndarray, shape (n,)
        Horizontal stretch of the equirectangular projection at each disc
        (``1 / sin φ``): a round object spans more columns away from the horizon.
    shape : (H, W)

    Returns
    -------
    index : ndarray of int64
        Flat indices (``row * W + column``) of the pixels with any coverage.
    coverage : ndarray of float32
        Their covered fraction in (0, 1], with a one-pixel linear ramp at the edges
        (anti-aliasing); overlapping discs saturate at 1.
    """
    height, width = shape
    if len(u) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float32)
    half_v = int(np.ceil(np.max(radius))) + 1
    half_u = int(np.ceil(np.max(radius * stretch))) + 1
    rows = np.floor(v + 0.5).astype(np.int64)[:, None] + np.arange(-half_v, half_v + 1)
    cols = np.floor(u + 0.5).astype(np.int64)[:, None] + np.arange(-half_u, half_u + 1)
    dy = (rows - v[:, None])[:, :, None]
    dx = ((cols - u[:, None]) / stretch[:, None])[:, None, :]
    cover = np.clip(radius[:, None, None] - np.sqrt(dx**2 + dy**2) + 0.5, 0.0, 1.0)
    flat, inside = _window_index(rows, cols, shape)
    total = np.bincount(flat.ravel(), np.where(inside, cover, 0.0).ravel(), height * width)
    index = np.flatnonzero(total)
    return index, np.minimum(total[index], 1.0).astype(np.float32)


def _window_integrals(
    first: NDArray[np.int64], centre: FloatArray, sigma: FloatArray, size: int
) -> FloatArray:
    """Pixel integrals of unit-peak Gaussians on a shared window per primitive.

    ``first`` (n,): first pixel index of each primitive's window; ``centre`` (n, S):
    sub-sample centres; ``sigma`` (n,). Returns weights (n, S, size).
    """
    index = (first[:, None] + np.arange(size))[:, None, :]
    scale = (np.sqrt(2.0) * sigma)[:, None, None]
    lower = erf((index - 0.5 - centre[:, :, None]) / scale)
    upper = erf((index + 0.5 - centre[:, :, None]) / scale)
    return 0.5 * (upper - lower) * (np.sqrt(2.0 * np.pi) * sigma)[:, None, None]


def streak_weights(
    u: FloatArray,
    v: FloatArray,
    sigma: FloatArray,
    du: FloatArray,
    dv: FloatArray,
) -> tuple[NDArray[np.int64], NDArray[np.int64], FloatArray]:
    """Pixel weights of Gaussian spots moving during the exposure (motion streaks).

    A spot of unit peak centred at ``(u, v)`` at mid-exposure moves by ``(du, dv)``
    pixels while the shutter is open; the image integrates it: the mean of unit-peak
    spots at sub-sample positions ``(u, v) + t (du, dv)``, ``t`` in ``[−½, ½]``, no
    more than 0.25 px apart. Without motion this is exactly a still spot.

    Returns
    -------
    rows, cols : ndarray of int64, shape (n, K)
        Pixel rows and (unwrapped) columns of each primitive's window.
    weight : ndarray, shape (n, K, K)
        Unit-peak-spot-equivalent weight of each pixel ``[row, col]``.
    """
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    du, dv = np.asarray(du, dtype=np.float64), np.asarray(dv, dtype=np.float64)
    length = float(np.max(np.hypot(du, dv), initial=0.0))
    steps = int(np.ceil(length / 0.25)) + 1
    t = np.linspace(-0.5, 0.5, steps) if steps > 1 else np.zeros(1)
    half = int(np.ceil(WINDOW_SIGMAS * np.max(sigma, initial=0.0) + 0.5 * length))
    size = 2 * half + 1
    row0 = np.floor(v + 0.5).astype(np.int64) - half
    col0 = np.floor(u + 0.5).astype(np.int64) - half
    wy = _window_integrals(row0, v[:, None] + t * dv[:, None], sigma, size)
    wx = _window_integrals(col0, u[:, None] + t * du[:, None], sigma, size)
    weight = np.einsum("nsk,nsl->nkl", wy, wx) / steps
    span = np.arange(size)
    return row0[:, None] + span, col0[:, None] + span, weight


def add_streaks(
    image: NDArray[np.float32],
    u: FloatArray,
    v: FloatArray,
    sigma: FloatArray,
    du: FloatArray,
    dv: FloatArray,
    rgb: FloatArray,
) -> None:
    """Add motion-streaked spots (`streak_weights`) with peak colour ``rgb`` (n, 3) to an
    ``(H, W, 3)`` image in place; columns wrap, rows outside the image are dropped."""
    if len(u) == 0:
        return
    rows, cols, weight = streak_weights(u, v, sigma, du, dv)
    flat, inside = _window_index(rows, cols, image.shape[:2])
    weight = np.where(inside, weight, 0.0)
    values = weight[..., None] * np.asarray(rgb)[:, None, None, :]
    np.add.at(image.reshape(-1, 3), flat.ravel(), values.reshape(-1, 3).astype(np.float32))


def peak_weight(
    u: FloatArray, v: FloatArray, sigma: FloatArray, du: FloatArray, dv: FloatArray
) -> FloatArray:
    """Largest pixel weight of each (streaked) unit-peak spot: the peak a flash of
    peak luma ``p`` actually adds to a pixel is ``p · peak_weight`` (pixel integration
    and streaking lower it). Computed in blocks to bound memory."""
    n = len(u)
    out = np.zeros(n)
    # Bound the (block, steps, K) and (block, K, K) arrays of `streak_weights` to ~1e7.
    length = float(np.max(np.hypot(du, dv), initial=0.0))
    size = 2 * np.ceil(WINDOW_SIGMAS * np.max(sigma, initial=0.0) + 0.5 * length) + 1
    steps = np.ceil(length / 0.25) + 1
    block = max(1, int(1e7 // (size * (2 * steps + size))))
    for lo in range(0, n, block):
        sl = slice(lo, lo + block)
        _, _, weight = streak_weights(u[sl], v[sl], sigma[sl], du[sl], dv[sl])
        out[sl] = weight.reshape(len(weight), -1).max(axis=1)
    return out
