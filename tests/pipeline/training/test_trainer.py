from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from pipeline.classify import FlashClassifier, ModelCard
from pipeline.training.metrics import roc_auc
from pipeline.training.trainer import (
    ONNX_INPUT,
    ONNX_OUTPUT,
    SCALE,
    TrainConfig,
    export_onnx,
    predict_logits,
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
    export_onnx(model, 1.7, path, SIZE)
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
    expected = torch_probabilities(model, 1.7, patches.images)
    np.testing.assert_allclose(classifier.predict(patches.images), expected, atol=1e-5)
    # the temperature is inside the graph: p = sigmoid(logit / 1.7)
    logits = predict_logits(model, patches.images)
    np.testing.assert_allclose(expected, 1 / (1 + np.exp(-logits / 1.7)), atol=1e-5)
    # dynamic batch: a batch size never seen at export
    assert classifier.predict(patches.images[:5]).shape == (5,)
