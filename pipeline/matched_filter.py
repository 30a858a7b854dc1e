"""The matched filter for point flashes on an equirectangular foreground.

A distant firefly is a point blurred by the lens to a spot of a pixel or two; the
filter that maximises its signal-to-noise ratio in white noise is the spot itself, a
Gaussian. Filtering with ``σ = 1`` px raises the SNR of a ``σ = 1`` px spot by about
1.8 over its brightest pixel, and suppresses single-pixel grain and compression
speckle. At high resolution the foreground is first averaged over ``b × b`` bins
(`binning`): spots there are several pixels wide, so little signal is lost, and the
filter, the noise estimate and the labelling all run on ``b²`` times fewer pixels.

Columns wrap around the 360° seam; the pole rows are replicated.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

#: Frame width above which the foreground is binned (one bin per this many columns).
BIN_WIDTH_PX = 1920


def binning(width: int, requested: int | None = None) -> int:
    """Bin side ``b`` for a frame `width` in pixels: `requested`, or ``round(width / 1920)``.

    A bin must divide the frame (equirectangular frames have even sides), so the
    automatic choice falls back to the largest divisor of the width at or below it.
    """
    if requested is not None:
        return requested
    b = max(1, round(width / BIN_WIDTH_PX))
    while width % b:
        b -= 1
    return b


def matched_filter(
    foreground: NDArray[np.float32], sigma_px: float, bin_px: int = 1
) -> NDArray[np.float32]:
    """Bin, then Gaussian-filter a foreground image.

    Parameters
    ----------
    foreground : ndarray of float32, shape (H, W)
        Frame minus background, grey levels (signed).
    sigma_px : float
        Gaussian ``σ`` in binned pixels; 0 disables the filter.
    bin_px : int
        Bin side ``b`` (1: no binning). ``H`` and ``W`` must be multiples of ``b``.

    Returns
    -------
    ndarray of float32, shape (H / b, W / b)
        The filtered foreground, grey levels (a bin holds the mean of its pixels; the
        filter kernel sums to 1).
    """
    height, width = foreground.shape
    image = foreground
    if bin_px > 1:
        size = (width // bin_px, height // bin_px)
        image = np.asarray(cv2.resize(foreground, size, interpolation=cv2.INTER_AREA))
    if sigma_px <= 0:
        return np.asarray(image, np.float32)
    pad = math.ceil(3 * sigma_px)
    wrapped = cv2.copyMakeBorder(image, 0, 0, pad, pad, cv2.BORDER_WRAP)
    filtered = cv2.GaussianBlur(wrapped, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
    return np.ascontiguousarray(filtered[:, pad:-pad], dtype=np.float32)
