"""Report plots (pipeline.report) on hand-made tables."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.report import plot_range_uncertainty


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
