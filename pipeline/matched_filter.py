"""The matched filter for point flashes on an equirectangular foreground.

A distant firefly is a point blurred by the lens to a spot of a pixel or two; the
filter that maximises its signal-to-noise ratio in white noise is the spot itself, a
Gaussian. Filtering with ``σ = 1`` px raises the SNR of a ``σ = 1`` px spot by about
1.8 over its brightest pixel, and suppresses single-pixel grain and compression
speckle. At high resolution the luminance is first averaged over ``b × b`` bins (`binning`,
`bin_image`) so that the background, the filter, the noise estimate and the labelling
run on ``b²`` times fewer pixels; the filter stays matched to the spot in pixels of the
recording (``σ / b`` bins), since real 4K spots are no wider than 1–2 px: at 4K a
filter of one bin (2 px) needs 1.5 and 1.3 times the peak SNR of the matched one to
lift a spot of σ 0.6 and 1 px to the same level (Gaussian spot, bins and filter).

Columns wrap around the 360° seam; the pole rows are replicated.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

#: Frame width above which the foreground is binned (one bin per this many columns).
BIN_WIDTH_PX = 1920
#: Largest automatic bin; a wider one is wider than a flash's spot (σ ≈ 1 px). At 5.7K, 3 × 3
#: bins (a filter of a third of a bin, hardly one) found 0.86/0.95 of the flash-frames ≥ 5 σ
#: of a tuning night (hard-clean s12, 5376 px) against 0.90/0.96 in 2 × 2 bins.
MAX_AUTO_BIN = 2


def binning(width: int, requested: int | None = None) -> int:
    """Bin side ``b`` for a frame `width` in pixels: `requested`, or ``round(width / 1920)``
    up to `MAX_AUTO_BIN`.

    A bin must divide the frame (equirectangular frames have even sides), so the
    automatic choice falls back to the largest divisor of the width at or below it.
    """
    if requested is not None:
        return requested
    b = min(MAX_AUTO_BIN, max(1, round(width / BIN_WIDTH_PX)))
    while width % b:
        b -= 1
    return b


def bin_image(
    image: NDArray[np.uint8], bin_px: int, out: NDArray[np.uint8] | None = None
) -> NDArray[np.uint8]:
    """Mean of ``bin_px × bin_px`` bins (rounded to grey levels), into `out` when given;
    the image itself for 1."""
    if bin_px == 1:
        return image
    height, width = image.shape
    size = (width // bin_px, height // bin_px)
    return np.asarray(cv2.resize(image, size, dst=out, interpolation=cv2.INTER_AREA), np.uint8)


def matched_filter(
    foreground: NDArray[np.float32], sigma_px: float, out: NDArray[np.float32] | None = None
) -> NDArray[np.float32]:
    """Gaussian-filter a foreground image, wrapping its columns at the 360° seam.

    Parameters
    ----------
    foreground : ndarray of float32, shape (H, W)
        Frame minus background, grey levels (signed).
    sigma_px : float
        Gaussian ``σ`` in pixels; 0 disables the filter.
    out : ndarray of float32, shape (H, W), optional
        Where to write the result (not `foreground` itself): a frame loop that reuses
        its buffers spares the kernel a fresh 4-bytes-a-pixel allocation per frame.

    Returns
    -------
    ndarray of float32, shape (H, W)
        The filtered foreground, grey levels (the kernel sums to 1).
    """
    if sigma_px <= 0:
        return foreground
    pad = math.ceil(3 * sigma_px)
    kernel = (2 * pad + 1, 2 * pad + 1)  # truncated at 3σ: the pad covers it exactly
    # The whole image with replicated borders, then its first and last columns again
    # from a narrow strip that joins the two edges (cheaper than padding the image).
    if foreground.shape[1] >= 4 * pad:
        filtered = np.asarray(
            cv2.GaussianBlur(
                foreground, kernel, sigma_px, dst=out, borderType=cv2.BORDER_REPLICATE
            ),
            np.float32,
        )
        strip = np.hstack([foreground[:, -2 * pad :], foreground[:, : 2 * pad]])
        joined = cv2.GaussianBlur(strip, kernel, sigma_px, borderType=cv2.BORDER_REPLICATE)
        filtered[:, :pad] = joined[:, 2 * pad : 3 * pad]
        filtered[:, -pad:] = joined[:, pad : 2 * pad]
        return filtered
    wrapped = cv2.copyMakeBorder(foreground, 0, 0, pad, pad, cv2.BORDER_WRAP)
    blurred = cv2.GaussianBlur(wrapped, kernel, sigma_px, borderType=cv2.BORDER_REPLICATE)
    if out is None:
        return np.ascontiguousarray(blurred[:, pad:-pad], dtype=np.float32)
    out[:] = blurred[:, pad:-pad]
    return out
