"""The matched-filter SNR of simulated flashes (pipeline.simulation.snr)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipeline.matched_filter import matched_filter
from pipeline.simulation.render import add_spots
from pipeline.simulation.snr import (
    filtered_noise,
    filtered_peak,
    grain_kernel,
    matched_filter_snr,
)


def _sensor_noise(shape: tuple[int, int], white: float, grain: float, grain_px: float):
    """The renderer's noise model: white noise plus Gaussian-smoothed grain of σ `grain`."""
    rng = np.random.default_rng(2)
    g = grain_kernel(grain_px)
    smooth = cv2.sepFilter2D(
        rng.standard_normal(shape).astype(np.float32), -1, g, g, borderType=cv2.BORDER_REFLECT
    )
    return white * rng.standard_normal(shape) + smooth * grain / np.sum(g**2)


@pytest.mark.parametrize(
    ("white", "grain", "grain_px"), [(2.0, 0.0, 1.2), (1.0, 1.5, 1.2), (0.5, 3.0, 0.6)]
)
def test_filtered_noise_matches_the_filtered_noise_image(
    white: float, grain: float, grain_px: float
) -> None:
    noise = _sensor_noise((600, 600), white, grain, grain_px).astype(np.float32)
    measured = matched_filter(noise, 1.0)[20:-20, 20:-20].std()
    assert measured == pytest.approx(float(filtered_noise(white, grain, grain_px)), rel=0.03)
    # Per pixel, the same noise is sqrt(white² + grain²): grain survives the filter.
    assert noise.std() == pytest.approx(np.hypot(white, grain), rel=0.03)


@pytest.mark.parametrize("psf", [0.6, 1.0, 2.0])
def test_filtered_peak_matches_the_filtered_rendered_spot(psf: float) -> None:
    image = np.zeros((64, 64, 3), np.float32)
    add_spots(image, np.array([32.0]), np.array([32.0]), np.array([psf]), np.full((1, 3), 100.0))
    luma = image[..., 1]
    amp = luma.max()
    peak = matched_filter(luma, 1.0).max()
    assert peak == pytest.approx(float(filtered_peak(amp, psf, 0.0)), rel=0.03)


def test_correlated_grain_lowers_the_snr_a_filter_sees() -> None:
    # The same per-pixel SNR (amplitude 10 over σ 2): white noise averages down under
    # the filter, grain of a flash's size hardly does.
    white = matched_filter_snr(10.0, 1.0, 0.0, 2.0, 0.0, 1.2)
    grainy = matched_filter_snr(10.0, 1.0, 0.0, 0.0, 2.0, 1.2)
    assert white > 2.5 * grainy
    assert 2.0 < float(grainy) < 5.0  # "5 σ" per pixel, under 4 σ after the filter
    streaked = matched_filter_snr(10.0, 1.0, 6.0, 2.0, 0.0, 1.2)
    assert streaked > white  # a streak of the same peak holds more light
