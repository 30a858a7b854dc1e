from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.classify import FlashClassifier, ModelCard
from pipeline.training.calibration import Platt
from pipeline.training.metrics import roc_auc
from pipeline.training.trainer import (
    ONNX_INPUT,
    ONNX_OUTPUT,
    SCALE,
    TrainConfig,
    export_onnx,
    predict_logits,
    sample_weights,
    torch_probabilities,
    train_model,
)
from tests.pipeline.training.conftest import SIZE, synthetic_patches

TINY = TrainConfig(epochs=4, batch_size=16, widths=(4, 8, 8), threads=1)


def test_tiny_training_learns_and_is_reproducible() -> None:
    train = synthetic_patches(per_class=8, seed=0)
    test = synthetic_patches(per_class=8, seed=1)
    a = train_model(train, TINY)
    b = train_model(train, TINY)
    for (name, pa), pb in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        assert torch.equal(pa, pb), name
    assert roc_auc(test.labels, predict_logits(a, test.images)) > 0.9
    c = train_model(train, replace(TINY, seed=1))
    assert not torch.equal(a.head[-1].weight, c.head[-1].weight)


def test_exported_onnx_agrees_with_torch(tmp_path: Path) -> None:
    patches = synthetic_patches(per_class=4)
    model = train_model(patches, replace(TINY, epochs=1))
    path = tmp_path / "tiny.onnx"
    platt = Platt(slope=0.6, intercept=-0.4)
    export_onnx(model, platt, path, SIZE)
    ModelCard(
        name="tiny",
        input_size=SIZE,
        input_name=ONNX_INPUT,
        output_name=ONNX_OUTPUT,
        scale=SCALE,
        output_kind="probability",
        threshold=0.5,
    ).write_json(tmp_path / "tiny.json")
    classifier = FlashClassifier.load(path)
    expected = torch_probabilities(model, platt, patches.images)
    np.testing.assert_allclose(classifier.predict(patches.images), expected, atol=1e-5)
    # the calibration is inside the graph: p = sigmoid(0.6 logit - 0.4)
    logits = predict_logits(model, patches.images)
    np.testing.assert_allclose(expected, 1 / (1 + np.exp(-(0.6 * logits - 0.4))), atol=1e-5)
    # dynamic batch: a batch size never seen at export
    assert classifier.predict(patches.images[:5]).shape == (5,)


def test_sample_weights_share_sources_equally_and_classes_by_square_root() -> None:
    sources = np.array(["gopro"] * 104 + ["sim"] * 10)
    labels = np.array([1] * 100 + [0] * 4 + [1] * 5 + [0] * 5)
    w = sample_weights(sources, labels, balance=True)
    assert w.mean() == pytest.approx(1.0)
    assert w[sources == "gopro"].sum() == pytest.approx(w[sources == "sim"].sum())
    gopro = w[:104]
    # classes of 100 and 4 patches: class totals in the ratio sqrt(100) : sqrt(4)
    assert gopro[:100].sum() / gopro[100:].sum() == pytest.approx(10 / 2)
    np.testing.assert_array_equal(sample_weights(sources, labels, balance=False), 1.0)
