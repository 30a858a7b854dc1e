import numpy as np
import pytest
from scipy.special import expit

from pipeline.training.calibration import choose_threshold, fit_temperature


def test_temperature_recovers_overconfidence() -> None:
    rng = np.random.default_rng(0)
    true_logit = rng.normal(0, 2, 20000)
    labels = (rng.random(true_logit.size) < expit(true_logit)).astype(int)
    overconfident = 3.0 * true_logit
    assert fit_temperature(overconfident, labels) == pytest.approx(3.0, rel=0.05)


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
