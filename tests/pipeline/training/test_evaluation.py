"""Held-out summaries: per source, one-class recordings count for recall or rejection only."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.training.dataset import PatchSet
from pipeline.training.evaluation import (
    failure_montage,
    format_summary,
    held_out_summary,
    plot_reliability,
)


def patch_set() -> tuple[PatchSet, np.ndarray]:
    """Source "phone": recording a (2 flashes, 2 backgrounds), recording b (3 flashes
    only); source "gopro": one recording of flashes. Probabilities chosen by hand."""
    labels = np.array([1, 1, 0, 0, 1, 1, 1, 1, 1], dtype=np.int8)
    groups = np.array(["a", "a", "a", "a", "b", "b", "b", "g", "g"])
    sources = np.array(["phone"] * 7 + ["gopro"] * 2)
    p = np.array([0.9, 0.3, 0.6, 0.1, 0.05, 0.8, 0.7, 0.9, 0.2])
    images = np.zeros((9, 33, 33, 3), np.uint8)
    return PatchSet(images, labels, groups, np.full(9, ""), sources), p


def test_summary_counts_one_class_recordings_for_recall_only() -> None:
    patches, p = patch_set()
    s = held_out_summary(patches, p, threshold=0.5)
    phone = s["phone"]
    # AUC over recording a only: flashes {0.9, 0.3} vs backgrounds {0.6, 0.1} -> 3/4
    assert phone["auc_two_class_recordings"] == pytest.approx(0.75)
    assert (phone["n_recordings"], phone["n_two_class_recordings"]) == (2, 1)
    # recall over all 5 phone flashes: 0.9, 0.8, 0.7 accepted
    assert phone["flash_recall"] == pytest.approx(3 / 5)
    assert phone["background_rejection"] == pytest.approx(1 / 2)
    assert phone["accuracy"] == pytest.approx(4 / 7, abs=1e-4)
    gopro = s["gopro"]
    assert gopro["auc_two_class_recordings"] is None and gopro["auc_pooled"] is None
    assert gopro["flash_recall"] == pytest.approx(0.5) and gopro["background_rejection"] is None
    assert sum(b["n"] for b in phone["reliability"]) == 7


def test_summary_text_and_figures(tmp_path: Path) -> None:
    patches, p = patch_set()
    s = held_out_summary(patches, p, threshold=0.5)
    text = format_summary(s, 0.5, "title")
    assert "flash recall at threshold 0.500 on gopro: 0.500 (2 flashes)" in text
    assert "flash recall at threshold 0.500 on phone: 0.600 (5 flashes)" in text
    assert "AUC2c" in text and "reliability" in text
    plot_reliability(s, tmp_path / "r.png", "title")
    assert cv2.imread(str(tmp_path / "r.png")) is not None
    counts = failure_montage(patches, p, 0.5, tmp_path / "f.png")
    assert counts == {"gopro": 1, "phone": 3}
    assert cv2.imread(str(tmp_path / "f.png")).shape[0] > 2 * 33
