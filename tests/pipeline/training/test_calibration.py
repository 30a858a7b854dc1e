import numpy as np
import pytest
from scipy.special import expit

from pipeline.training.calibration import choose_threshold, fit_platt, reliability


def test_platt_recovers_slope_and_shift() -> None:
    rng = np.random.default_rng(0)
    true_logit = rng.normal(0, 2, 20000)
    labels = (rng.random(true_logit.size) < expit(true_logit)).astype(int)
    raw = 3.0 * true_logit + 1.5  # overconfident and biased towards flashes
    platt = fit_platt(raw, labels)
    assert platt.slope == pytest.approx(1 / 3, rel=0.05)
    assert platt.intercept == pytest.approx(-0.5, abs=0.1)
    bins = reliability(labels, platt(raw))
    assert all(abs(b["predicted"] - b["observed"]) < 0.05 for b in bins if b["n"] > 500)
    assert sum(b["n"] for b in bins) == len(labels)


def test_platt_weights_count_each_sample_by_its_weight() -> None:
    rng = np.random.default_rng(1)
    z = rng.normal(0, 1, 4000)
    labels = (rng.random(4000) < expit(z)).astype(int)
    doubled = fit_platt(np.concatenate([z, z[:1000]]), np.concatenate([labels, labels[:1000]]))
    weights = np.ones(4000)
    weights[:1000] = 2
    weighted = fit_platt(z, labels, weights)
    assert weighted.slope == pytest.approx(doubled.slope, rel=1e-3)
    assert weighted.intercept == pytest.approx(doubled.intercept, abs=1e-3)


def test_threshold_maximises_accuracy() -> None:
    labels = np.array([0, 0, 0, 1, 0, 1, 1, 1])
    p = np.array([0.1, 0.2, 0.3, 0.4, 0.55, 0.6, 0.7, 0.9])
    t = choose_threshold(labels, p)
    # best: accept > 0.35 (one error: 0.55) or > 0.575 (one error: 0.4); median candidate
    assert ((p > t) == labels.astype(bool)).sum() == 7
    assert 0.3 < t < 0.6


def test_threshold_on_separable_scores_separates() -> None:
    p = np.array([0.05, 0.2, 0.3, 0.8, 0.95])
    labels = np.array([0, 0, 0, 1, 1])
    t = choose_threshold(labels, p)
    assert 0.3 < t < 0.8


def test_weights_let_a_small_source_count() -> None:
    big_p = np.array([0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8])
    big_y = np.array([0] * 8 + [1] * 2)  # alone: best cut in (0.6, 0.7)
    small_p = np.array([0.25, 0.35, 0.45, 0.55, 0.65])
    small_y = np.array([0, 1, 1, 1, 1])  # alone: best cut in (0.25, 0.35)
    p, y = np.concatenate([big_p, small_p]), np.concatenate([big_y, small_y])
    assert choose_threshold(y, p) > 0.5  # unweighted, the big source wins: 12 of 15 right
    weights = np.concatenate([np.full(10, 1 / 10), np.full(5, 1 / 5)])
    # per-source accuracies at 0.325: 7/10 + 5/5 = 1.7, the best mean
    assert 0.3 < choose_threshold(y, p, weights) < 0.35
