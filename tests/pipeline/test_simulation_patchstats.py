"""Patch statistics that compare simulated flashes with the real labelled ones."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.simulation.patchstats import STATS, patch_stats


def _patches(background: np.ndarray) -> np.ndarray:
    """RGB patches of a given green background with a 3×3 flash of 100 at the centre."""
    rgb = np.repeat(background[..., None], 3, axis=-1).astype(np.float64)
    c = rgb.shape[1] // 2
    rgb[:, c - 1 : c + 2, c - 1 : c + 2, :] += 100.0
    return np.clip(rgb, 0, 255).astype(np.uint8)


def test_a_flat_background_and_recorded_grain_are_told_apart() -> None:
    rng = np.random.default_rng(0)
    flat = np.full((50, 33, 33), 5.0)
    grain = 20.0 + rng.normal(0.0, 2.0, (50, 33, 33))
    stats_flat, stats_grain = patch_stats(_patches(flat)), patch_stats(_patches(grain))
    assert set(stats_flat) == set(STATS)
    assert np.all(stats_flat["flat_share"] == 1.0) and np.all(stats_flat["background_sd"] == 0)
    assert np.all(stats_flat["contrast"] == 100) and np.all(stats_flat["area"] == 9)
    # Independent grain of σ 2 in whole grey levels: neighbours agree with probability
    # Σ p_k² ≈ 1 / (2 √π σ).
    expected = 1.0 / (2.0 * np.sqrt(np.pi) * 2.0)
    assert np.median(stats_grain["flat_share"]) == pytest.approx(expected, abs=0.03)
    assert np.median(stats_grain["background_sd"]) == pytest.approx(2.0, abs=0.2)
