"""Report plots (pipeline.report) on hand-made tables."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.report import plot_range_uncertainty, plot_residuals


def test_range_uncertainty_is_plotted_with_or_without_standard_deviations(
    tmp_path: Path,
) -> None:
    table = {"range_m": np.array([3.0, 9.0, 18.0]), "range_sd_m": np.array([0.01, 0.1, 0.9])}
    plot_range_uncertainty(table, tmp_path / "now.png")
    # Results of earlier releases have no range_sd_m column: an empty plot, no error.
    plot_range_uncertainty({"range_m": table["range_m"]}, tmp_path / "earlier.png")
    for name in ("now.png", "earlier.png"):
        with Image.open(tmp_path / name) as image:
            assert image.size == (600, 350)


def test_residuals_get_a_panel_for_each_fit_with_pairs(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    first = {"residuals": rng.exponential(0.05, 40), "inliers": np.arange(40) < 36}
    refit = {"residuals": rng.exponential(0.03, 200), "inliers": np.arange(200) < 190}
    kept = {"residuals": np.zeros(0), "inliers": np.zeros(0, bool)}
    plot_residuals({"first": first, "refit": refit}, tmp_path / "both.png")
    plot_residuals({"first": first, "refit": kept}, tmp_path / "first.png")
    plot_residuals({"refit": kept}, tmp_path / "none.png")
    with Image.open(tmp_path / "both.png") as both, Image.open(tmp_path / "first.png") as one:
        assert both.size == (1200, 350) and one.size == (600, 350)
    with Image.open(tmp_path / "none.png") as none:
        assert none.size == (600, 350)
