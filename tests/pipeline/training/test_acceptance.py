"""Training the evidence model (pipeline.training.acceptance)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.evidence_features import FEATURES
from pipeline.evidence_model import EvidenceModel
from pipeline.params import ProcessParams, TrackingParams
from pipeline.training.acceptance import (
    Night,
    best_f1_threshold,
    common_tracking,
    equal_false_threshold,
    stacked_links,
    train,
)
from tests.pipeline.links_factory import links_apart

NARROW = TrackingParams(matched_sigma_px=0.75)


def test_the_f1_threshold_cuts_between_distinct_probabilities() -> None:
    probability = np.array([0.9, 0.8, 0.8, 0.6, 0.3, 0.2])
    is_flash = np.array([True, True, False, True, False, False])
    # Cuts: 0.9 → F1 2/4; 0.8 → 4/6; 0.6 → 6/7; 0.3 → 6/8: the best is 0.6.
    assert best_f1_threshold(probability, is_flash) == 0.6


def _pairs(n: int) -> np.ndarray:
    """Stereo partners: rows 0 and 1 matched, 2 and 3, …, the last quarter unmatched."""
    partner = np.arange(n) ^ 1
    partner[3 * n // 4 :] = -1
    return partner


def _night(seed: int, scenario: str, rng: np.random.Generator) -> Night:
    n = 600
    rows = rng.normal(size=(n, len(FEATURES)))
    rows[:, FEATURES.index("stereo_matched")] = rng.random(n) < 0.5
    # A flash: high SNR, or a weaker one the other camera confirms.
    snr = rows[:, FEATURES.index("snr_log")]
    matched = rows[:, FEATURES.index("stereo_matched")] == 1
    is_flash = (snr + 1.5 * matched + rng.normal(0, 0.1, n)) > 1.0
    links = links_apart(np.arange(n), _pairs(n))
    return Night(f"{scenario} s{seed}", scenario, seed, rows, is_flash, links)  # kind: scenario


def test_a_model_learns_evidence_and_writes_its_card(tmp_path) -> None:
    rng = np.random.default_rng(0)
    nights = [_night(seed, scenario, rng) for seed in (1, 2, 3) for scenario in ("a", "b")]
    model, figures = train(nights, "flashnet2.onnx", NARROW, seed=0, folds=3)
    assert set(figures) == {"a", "b"}
    assert all(f["precision"] > 0.9 and f["recall_of_candidates"] > 0.9 for f in figures.values())
    assert model.card["trained_on"] == [n.name for n in nights]
    path = tmp_path / "model.json"
    model.to_json(path)
    back = EvidenceModel.load(path)
    assert back.threshold == model.threshold and back.classifier == "flashnet2.onnx"
    assert back.tracking == NARROW.model_dump(mode="json")
    test = _night(9, "a", rng)
    accepted = back.probability(test.rows) >= back.threshold
    assert np.mean(accepted == test.is_flash) > 0.9


def test_a_given_threshold_is_kept_and_scored_out_of_fold() -> None:
    rng = np.random.default_rng(1)
    nights = [_night(seed, "a", rng) for seed in (1, 2, 3)]
    best, _ = train(nights, "flashnet2.onnx", TrackingParams(), seed=0, folds=3)
    strict, figures = train(
        nights, "flashnet2.onnx", TrackingParams(), seed=0, threshold=0.95, folds=3
    )
    assert best.card["threshold_chosen_by"] == "largest out-of-fold F1"
    assert strict.threshold == 0.95 and strict.card["threshold_chosen_by"] == "given"
    loose = best.card["out_of_fold_at_threshold"]["a"]
    assert figures["a"]["accepted"] < loose["accepted"]  # a stricter cut accepts fewer
    assert figures["a"]["precision"] >= loose["precision"]


def test_a_model_learns_the_candidates_of_one_tracking() -> None:
    narrow = ProcessParams(tracking=NARROW)
    assert common_tracking([narrow, narrow]) == NARROW
    with pytest.raises(ValueError, match=r"matched_sigma_px \['0.75', '1.0'\]"):
        common_tracking([narrow, ProcessParams()])
    merged = ProcessParams(tracking=TrackingParams(deblend=False))
    with pytest.raises(ValueError, match=r"deblend \['False', 'True'\]"):
        common_tracking([ProcessParams(), merged])
    with pytest.raises(ValueError, match="no runs"):
        common_tracking([])


def _linked_night(seed: int, rng: np.random.Generator) -> Night:
    """Flashes lit 4 frames: each candidate's own evidence is a noisy reading of its
    light curve's, so only the light curve as a whole tells a dim frame of a flash from
    a bright speck of grain."""
    n_curves, length = 300, 4
    flash = rng.random(n_curves) < 0.5
    curve = np.repeat(np.arange(n_curves), length)
    rows = rng.normal(size=(len(curve), len(FEATURES)))
    rows[:, FEATURES.index("snr_log")] = flash[curve] + rng.normal(0, 0.7, len(curve))
    links = links_apart(curve, _pairs(len(curve)))
    return Night(f"a s{seed}", "a", seed, rows, flash[curve], links)


def test_the_second_pass_learns_what_a_light_curve_shares() -> None:
    rng = np.random.default_rng(2)
    model, figures = train(
        [_linked_night(s, rng) for s in (1, 2, 3)], "m.onnx", TrackingParams(), folds=3
    )
    first = model.card["first_pass_out_of_fold_at_threshold"]
    second = figures["a"]
    assert second["precision"] > first["precision"] + 0.05
    assert second["recall_of_candidates"] > first["recall_of_candidates"]
    test = _linked_night(9, rng)
    right = [
        np.mean((model.probability(test.rows, links) >= model.threshold) == test.is_flash)
        for links in (None, test.links)  # the first pass alone, then both
    ]
    assert right[1] > right[0] + 0.05, right


def test_the_equal_false_cut_accepts_at_most_that_many_false_rows() -> None:
    p = np.array([0.9, 0.8, 0.8, 0.7, 0.6, 0.3])
    is_flash = np.array([True, False, False, True, False, True])
    assert equal_false_threshold(p, is_flash, 0) > 0.8 >= equal_false_threshold(p, is_flash, 2)
    assert equal_false_threshold(p, is_flash, 1) > 0.8  # the tie at 0.8 is two, not one
    assert 0.6 < equal_false_threshold(p, is_flash, 2) <= 0.7
    assert equal_false_threshold(p, is_flash, 3) == 0.0  # every row


def test_a_retrained_model_can_keep_the_first_passs_false_count() -> None:
    rng = np.random.default_rng(3)
    nights = [_linked_night(s, rng) for s in (1, 2, 3)]
    model, _ = train(nights, "m.onnx", TrackingParams(), folds=3, first_pass_cut=0.5)
    card = model.card
    assert card["threshold_chosen_by"] == "the first pass's out-of-fold false count at 0.5"
    kept = train(nights, "m.onnx", TrackingParams(), folds=3, threshold=0.5)[0].card
    first = kept["first_pass_out_of_fold_at_threshold"]
    both = sum(f["accepted"] - f["true"] for f in card["out_of_fold_at_threshold"].values())
    assert both <= first["accepted"] - first["true"]
    # ...and finds more flashes for them: what the light curve shares is worth it.
    assert sum(f["true"] for f in card["out_of_fold_at_threshold"].values()) > first["true"]


def test_nights_links_stack_without_joining_them() -> None:
    a = links_apart(np.array([0, 0, 1]), np.array([2, -1, 0]))
    b = links_apart(np.array([0, 1]), np.array([1, 0]))
    both = stacked_links([a, b])
    assert both.light_curve.tolist() == [0, 0, 1, 2, 3]
    assert both.partner.tolist() == [2, -1, 0, 4, 3]
