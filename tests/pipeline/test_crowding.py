"""Seeds beside brighter spots (`pipeline.crowding`) on synthetic filter responses."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from pipeline.blobs import PixelIndex, label, local_maxima
from pipeline.crowding import CrowdedSeeds, crowded_seeds

H, W = 40, 80
SEED = 4.0
EXTENT = 2.5


def _response(spots: list[tuple[float, float, float, float]], noise: float = 0.0) -> NDArray:
    """Gaussian spots ``(row, col, amplitude, sigma)`` on noise of σ `noise` as the
    matched filter (σ 1 px) leaves it: correlated over neighbouring pixels. Columns wrap
    at the seam."""
    rows, cols = np.mgrid[0:H, 0:W].astype(np.float64)
    white = np.random.default_rng(3).normal(0.0, 1.0, (H, W + 8))
    smooth = cv2.GaussianBlur(white, (0, 0), 1.0)[:, 4:-4]
    image = noise * smooth / smooth.std()
    for r, c, a, s in spots:
        dc = (cols - c + W / 2) % W - W / 2
        image += a * np.exp(-((rows - r) ** 2 + dc**2) / (2 * s**2))
    return image.astype(np.float32)


def _seeds(response: NDArray[np.float32]) -> tuple[NDArray[np.intp], CrowdedSeeds]:
    """The tracker's seeds (local maxima within 2 px reaching the seed level) and the
    crowded ones, for a noise σ of 1."""
    idx = np.flatnonzero(response.ravel() > EXTENT)
    snr = response.ravel()[idx].astype(np.float64)
    pixels = PixelIndex((H, W), 2)
    pixels.assign(idx)
    blobs = label(pixels)
    peaks = local_maxima(pixels, snr, 2, snr >= SEED)
    return idx[peaks], crowded_seeds(pixels, idx, snr, response, blobs, peaks, SEED, 1)


def test_a_faint_flash_on_a_bright_ones_slope_gets_a_seed_of_its_own() -> None:
    response = _response([(20.0, 30.0, 60.0, 1.5), (21.3, 33.6, 12.0, 1.5)])
    peaks, crowded = _seeds(response)
    assert len(peaks) == 1  # a shoulder, no local maximum
    assert len(crowded.at) == 1
    assert abs(crowded.row[0] - 21.3) < 0.3 and abs(crowded.col[0] - 33.6) < 0.3
    assert 10.0 < crowded.snr[0] < 14.0  # its own light, not the bright one's too


def test_lone_spots_and_noise_get_no_second_seed() -> None:
    response = _response([(10.0, 20.0, 80.0, 1.2), (25.0, 60.0, 30.0, 2.1)], noise=1.0)
    peaks, crowded = _seeds(response)
    assert len(peaks) == 2
    assert len(crowded.at) == 0


def test_a_light_wider_than_a_point_is_not_taken_apart() -> None:
    # A glow of σ 4 px with a bump: not a Gaussian point spread, left to acceptance.
    response = _response([(20.0, 40.0, 40.0, 4.0), (20.0, 46.0, 10.0, 1.2)])
    _, crowded = _seeds(response)
    assert len(crowded.at) == 0


def test_a_pair_across_the_seam_is_taken_apart() -> None:
    response = _response([(20.0, W - 1.5, 50.0, 1.4), (20.0, 2.0, 15.0, 1.4)])
    peaks, crowded = _seeds(response)
    assert len(peaks) == 1
    assert len(crowded.at) == 1
    # The bright spot's fit takes in some of the faint one's light: a third of a pixel.
    assert abs((crowded.col[0] - 2.0 + W / 2) % W - W / 2) < 0.5
