import numpy as np
import pytest

from pipeline.training.metrics import (
    expected_calibration_error,
    log_loss,
    roc_auc,
    score,
    score_by_group,
)


def test_roc_auc_counts_pairs_and_half_ties() -> None:
    labels = np.array([1, 0, 1, 0, 1])
    scores = np.array([0.9, 0.8, 0.3, 0.1, 0.8])
    # positive-negative pairs: (.9,.8) 1, (.9,.1) 1, (.3,.8) 0, (.3,.1) 1, (.8,.8) 0.5, (.8,.1) 1
    assert roc_auc(labels, scores) == pytest.approx(4.5 / 6)


def test_roc_auc_is_nan_with_one_class() -> None:
    assert np.isnan(roc_auc(np.ones(3), np.array([0.1, 0.2, 0.3])))


def test_score_at_threshold_matches_hand_count() -> None:
    labels = np.array([1, 1, 1, 0, 0, 0, 0])
    p = np.array([0.9, 0.6, 0.2, 0.7, 0.1, 0.3, 0.5])
    s = score(labels, p, threshold=0.5)  # accepted: .9 .6 .7 ; 0.5 itself is not > 0.5
    assert (s.n, s.n_flash) == (7, 3)
    assert s.precision == pytest.approx(2 / 3)
    assert s.recall == pytest.approx(2 / 3)
    assert s.accuracy == pytest.approx(5 / 7)  # tp 2 + tn 3
    expected_loss = -np.mean(np.log([0.9, 0.6, 0.2, 0.3, 0.9, 0.7, 0.5]))
    assert s.log_loss == pytest.approx(expected_loss)


def test_precision_is_nan_when_nothing_accepted() -> None:
    s = score(np.array([1, 0]), np.array([0.1, 0.2]), 0.5)
    assert np.isnan(s.precision)
    assert s.recall == 0.0


def test_score_by_group_splits_rows() -> None:
    labels = np.array([1, 0, 1, 1])
    p = np.array([0.9, 0.2, 0.1, 0.8])
    groups = np.array(["a", "a", "b", "b"])
    by = score_by_group(labels, p, groups, 0.5)
    assert list(by) == ["a", "b"]
    assert by["a"].accuracy == 1.0 and by["a"].auc == 1.0
    assert by["b"].accuracy == 0.5 and np.isnan(by["b"].auc)


def test_log_loss_clips_certain_mistakes() -> None:
    assert np.isfinite(log_loss(np.array([1]), np.array([0.0])))


def test_expected_calibration_error() -> None:
    labels = np.array([1, 0, 1, 1])
    p = np.array([0.05, 0.05, 0.95, 0.95])
    # bin 0: mean label .5 vs .05 -> .45, weight 1/2; bin 9: 1 vs .95 -> .05, weight 1/2
    assert expected_calibration_error(labels, p) == pytest.approx(0.25)
