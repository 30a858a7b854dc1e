"""The SNR a simulated flash offers a matched filter, from the simulator's noise model.

The truth's ``snr`` is the drawn peak over the per-pixel sensor noise σ. A detector
that filters the image sees less: white read and shot noise average down under the
filter, but grain that is correlated over a flash's size does not. ``snr_mf`` is the
SNR at the peak of a Gaussian filter of σ ``filter_px`` (the tracker's matched filter at
bin 1), against the sensor noise alone: the yardstick for "could a matched filter have
found it" that the swaying background and the tracker's own noise estimate don't enter.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Variance of a uniform pixel footprint (1 px wide) added to a spot by integration.
PIXEL_VARIANCE = 1.0 / 12.0


def grain_kernel(grain_px: float) -> NDArray[np.float64]:
    """The 1-D Gaussian (σ `grain_px`, ±4 σ, unit sum) the renderer smooths grain with."""
    size = 2 * math.ceil(4 * grain_px) + 1
    return np.asarray(cv2.getGaussianKernel(size, grain_px, cv2.CV_64F), np.float64).ravel()


def _filter_kernel(filter_px: float) -> NDArray[np.float64]:
    """`pipeline.matched_filter`'s 1-D kernel (±3 σ, unit sum)."""
    size = 2 * math.ceil(3 * filter_px) + 1
    return np.asarray(cv2.getGaussianKernel(size, filter_px, cv2.CV_64F), np.float64).ravel()


def filtered_noise(
    white_sigma: ArrayLike, grain_sigma: float, grain_px: float, filter_px: float = 1.0
) -> NDArray[np.float64]:
    """σ of sensor noise after a Gaussian filter of σ `filter_px` (grey levels).

    White noise of σ ``s`` filtered by the separable kernel ``k ⊗ k`` keeps σ
    ``s · Σ k²``; grain (white noise smoothed by ``g ⊗ g`` and scaled to `grain_sigma`
    per pixel) keeps ``grain_sigma · Σ (g * k)² / Σ g²``. Exact for the renderer's
    discrete kernels, away from the image's borders.
    """
    k = _filter_kernel(filter_px)
    white = np.asarray(white_sigma, dtype=np.float64) * np.sum(k**2)
    if grain_sigma <= 0:
        return white
    g = grain_kernel(grain_px)
    grain = grain_sigma * np.sum(np.convolve(g, k) ** 2) / np.sum(g**2)
    return np.hypot(white, grain)


def filtered_peak(
    amp: ArrayLike, psf_px: ArrayLike, streak_px: ArrayLike, filter_px: float = 1.0
) -> NDArray[np.float64]:
    """Peak response of a unit-sum Gaussian filter of σ `filter_px` to a flash.

    The flash is taken as an elliptical Gaussian of peak `amp`: σ² ``psf² + 1/12``
    across its motion (the PSF integrated over a pixel) and ``psf² + 1/12 + L²/12``
    along it (a streak of length ``L`` = `streak_px`). Its filtered peak is
    ``amp · σa σc / √((σa² + f²)(σc² + f²))``.
    """
    across = np.asarray(psf_px, dtype=np.float64) ** 2 + PIXEL_VARIANCE
    along = across + np.asarray(streak_px, dtype=np.float64) ** 2 / 12.0
    f2 = filter_px**2
    gain = np.sqrt(across * along / ((across + f2) * (along + f2)))
    return np.asarray(amp, dtype=np.float64) * gain


def matched_filter_snr(
    amp: ArrayLike,
    psf_px: ArrayLike,
    streak_px: ArrayLike,
    white_sigma: ArrayLike,
    grain_sigma: float,
    grain_px: float,
    filter_px: float = 1.0,
) -> NDArray[np.float64]:
    """SNR of each flash at the peak of a Gaussian filter of σ `filter_px`.

    Parameters
    ----------
    amp : array_like
        Drawn peak amplitude of the flash, grey levels (luma).
    psf_px, streak_px : array_like
        Point-spread σ and motion-streak length, pixels.
    white_sigma : array_like
        σ of the uncorrelated sensor noise at the flash's pixel (read and shot noise),
        grey levels.
    grain_sigma, grain_px : float
        Per-pixel σ of the grain (grey levels) and the σ of its smoothing kernel (px).
    filter_px : float
        σ of the matched filter, pixels.

    Returns
    -------
    ndarray of float64
        `filtered_peak` / `filtered_noise`.
    """
    noise = filtered_noise(white_sigma, grain_sigma, grain_px, filter_px)
    return filtered_peak(amp, psf_px, streak_px, filter_px) / np.maximum(noise, 1e-9)
