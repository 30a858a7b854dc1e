import numpy as np
import pytest

from pipeline.training.baseline import FEATURE_NAMES, LogisticRegression, contrast_features
from pipeline.training.metrics import roc_auc
from tests.pipeline.training.conftest import synthetic_patches


def test_logistic_regression_recovers_the_generating_direction() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(4000, 3)) * [1.0, 2.0, 0.5] + [0.0, 5.0, 0.0]
    true_w = np.array([2.0, -1.0, 0.0])
    labels = (rng.random(len(x)) < 1 / (1 + np.exp(-(x - [0, 5, 0]) @ true_w))).astype(int)
    model = LogisticRegression.fit(x, labels, l2=1e-4)
    w = model.weights / model.std  # back to raw feature units
    np.testing.assert_allclose(w / np.linalg.norm(w), true_w / np.linalg.norm(true_w), atol=0.05)
    p = model.predict_proba(x)
    assert ((p > 0.5) == labels).mean() > 0.8


def test_features_of_a_lone_dot() -> None:
    patch = np.zeros((1, 33, 33, 3), np.uint8)
    patch[0, 15:18, 15:18] = [90, 150, 60]  # 3x3 yellow-green dot, luminance 100
    f = dict(zip(FEATURE_NAMES, contrast_features(patch)[0], strict=True))
    assert f["log_centre"] == pytest.approx(np.log1p(100))
    assert f["centre3_minus_ring"] == pytest.approx(100)
    assert f["log_blob_area"] == pytest.approx(np.log1p(9))
    assert f["log_bright_outside"] == 0
    assert f["centre_green_share"] == pytest.approx(150 / 301)
    assert f["log_outer"] == 0


def test_baseline_separates_synthetic_patches() -> None:
    patches = synthetic_patches(per_class=20)
    features = contrast_features(patches.images)
    model = LogisticRegression.fit(features, patches.labels)
    assert roc_auc(patches.labels, model.predict_proba(features)) > 0.95
