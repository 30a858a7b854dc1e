"""The matched filter for point flashes (pipeline.matched_filter)."""

from __future__ import annotations

import numpy as np

from pipeline.matched_filter import bin_image, binning, matched_filter


def _spot(shape: tuple[int, int], u: float, v: float, amplitude: float, sigma: float) -> np.ndarray:
    rows, cols = np.mgrid[: shape[0], : shape[1]]
    du = (cols - u + shape[1] / 2) % shape[1] - shape[1] / 2
    return (amplitude * np.exp(-(du**2 + (rows - v) ** 2) / (2 * sigma**2))).astype(np.float32)


def test_the_filter_raises_the_snr_of_a_point_flash() -> None:
    rng = np.random.default_rng(3)
    noise = rng.normal(0, 1.0, (256, 512)).astype(np.float32)
    spot = _spot(noise.shape, 200.0, 100.0, 6.0, 1.0)  # 6 σ at its brightest pixel
    raw_snr = (spot + noise)[100, 200] / noise.std()
    filtered_noise = matched_filter(noise, 1.0)
    filtered = matched_filter(spot + noise, 1.0)
    gain = (filtered[100, 200] / filtered_noise.std()) / raw_snr
    # Theory for white noise: peak A/2, noise σ / (2 √π σ_f): gain √π ≈ 1.77.
    assert 1.4 < gain < 2.2


def test_the_filter_wraps_around_the_seam() -> None:
    image = _spot((64, 128), 0.0, 32.0, 100.0, 1.0)
    filtered = matched_filter(image, 1.0)
    # Equal to filtering the image padded with its own other side.
    padded = np.hstack([image[:, -8:], image, image[:, :8]])
    np.testing.assert_allclose(filtered, matched_filter(padded, 1.0)[:, 8:-8], atol=1e-4)
    assert abs(filtered[32, 1] - filtered[32, 127]) < 1e-2  # symmetric about column 0
    assert filtered[32, 127] > 10


def test_binning_averages_and_is_chosen_from_the_width() -> None:
    image = np.arange(0, 64, 4, dtype=np.uint8).reshape(4, 4)
    np.testing.assert_array_equal(bin_image(image, 2), [[10, 18], [42, 50]])
    assert bin_image(image, 1) is image
    assert binning(640) == 1 and binning(1280) == 1 and binning(3840) == 2
    assert binning(5760) == 2 and binning(7680) == 2 and binning(5760, requested=3) == 3
    assert binning(3840, requested=1) == 1
