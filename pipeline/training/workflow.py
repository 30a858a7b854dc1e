"""``train-classifier`` end to end: grouped CV, calibration, final fit, export, card."""

from __future__ import annotations

import platform
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.special import expit

from pipeline.classify import FlashClassifier, ModelCard
from pipeline.training.calibration import choose_threshold, fit_temperature
from pipeline.training.dataset import PatchSet
from pipeline.training.evaluation import (
    Predictions,
    baseline_predictions,
    compare,
    comparison_dict,
    format_comparison,
    reference_predictions,
)
from pipeline.training.metrics import expected_calibration_error, log_loss
from pipeline.training.model import FlashNet
from pipeline.training.splits import grouped_folds
from pipeline.training.trainer import (
    ONNX_INPUT,
    ONNX_OPSET,
    ONNX_OUTPUT,
    SCALE,
    TrainConfig,
    export_onnx,
    out_of_fold_logits,
    torch_probabilities,
    train_model,
)

#: Largest tolerated |onnxruntime − torch| probability difference after export.
EXPORT_TOLERANCE = 1e-4


@dataclass(frozen=True)
class TrainingRun:
    """What ``train-classifier`` produced."""

    card: ModelCard
    report: str
    export_error: float


def train_classifier(
    parts: Sequence[PatchSet],
    out: Path,
    config: TrainConfig,
    cv_folds: int,
    input_size: int,
    provenance: Mapping[str, object],
    reference: FlashClassifier | None = None,
    progress: Callable[[int], None] | None = None,
) -> TrainingRun:
    """Cross-validate, calibrate, train on everything and write ``out`` + its card.

    1. Grouped ``cv_folds``-fold CV (whole recordings held out; folds balanced in
       class × data source) gives an out-of-fold logit for every patch.
    2. A temperature is fitted to those logits and the acceptance threshold chosen on
       the calibrated out-of-fold probabilities (highest accuracy): both come from
       recordings the predicting model never saw.
    3. The final network is trained on all patches with the same seed and exported
       with the temperature and the sigmoid inside the graph; onnxruntime's output is
       checked against torch's.

    Parameters
    ----------
    parts : one patch set per data folder, at the folder's own patch size.
    out : ONNX path; the card is written beside it (``.json``).
    config : hyper-parameters and seed.
    cv_folds : number of grouped folds.
    input_size : patch side of the network (patches are centre-cropped/edge-padded).
    provenance : data folders, command, ... for the card's ``training``.
    reference : a published model to compare with on sources of large enough patches.
    progress : called with 1 per epoch ((cv_folds + 1) * epochs in all).
    """
    patches = PatchSet.concat([p.resized(input_size) for p in parts])
    folds = grouped_folds(patches.groups, patches.strata(), cv_folds, config.seed)
    logits = out_of_fold_logits(patches, folds, config, progress)
    temperature = fit_temperature(logits, patches.labels)
    oof = expit(logits / temperature)
    threshold = choose_threshold(patches.labels, oof, _per_source_weights(patches))
    models = [
        Predictions(f"{out.stem} (grouped CV, calibrated)", oof, threshold),
        baseline_predictions(patches, folds),
    ]
    if reference is not None:
        models.append(reference_predictions(reference, parts))
    comparison = compare(patches, models)

    model = train_model(patches, config, progress)
    export_onnx(model, temperature, out, input_size)
    card = ModelCard(
        name=out.stem,
        input_size=input_size,
        input_name=ONNX_INPUT,
        output_name=ONNX_OUTPUT,
        layout="NCHW",
        channel_order="RGB",
        scale=SCALE,
        output_kind="probability",
        threshold=threshold,
        training={
            **provenance,
            "n_patches": len(patches),
            "n_flash": int(patches.labels.sum()),
            "n_recordings": len(np.unique(patches.groups)),
            "config": asdict(config),
            "temperature": round(temperature, 4),
            "threshold_rule": (
                "highest accuracy on calibrated out-of-fold probabilities, "
                "each data source weighing the same"
            ),
            "onnx_opset": ONNX_OPSET,
            "torch": torch.__version__,
            "python": platform.python_version(),
        },
        evaluation={
            "protocol": f"{cv_folds}-fold grouped CV, whole source recordings held out",
            "out_of_fold_calibration": {
                "uncalibrated": _calibration(patches.labels, expit(logits)),
                "temperature_scaled": _calibration(patches.labels, oof),
            },
            "by_source": comparison_dict(comparison),
        },
    )
    card_path = out.with_suffix(".json")
    card.write_json(card_path)
    error = _export_error(model, temperature, out, card_path, patches.images)
    title = (
        f"grouped {cv_folds}-fold CV on {len(patches)} patches from "
        f"{len(np.unique(patches.groups))} recordings (temperature {temperature:.3f})"
    )
    return TrainingRun(card, format_comparison(comparison, title), error)


def _calibration(labels: np.ndarray, probabilities: np.ndarray) -> dict[str, float]:
    return {
        "log_loss": round(log_loss(labels, probabilities), 4),
        "expected_calibration_error": round(expected_calibration_error(labels, probabilities), 4),
    }


def _per_source_weights(patches: PatchSet) -> np.ndarray:
    """1 / (size of the patch's data source): every source counts the same."""
    _, index, counts = np.unique(patches.sources, return_inverse=True, return_counts=True)
    return 1.0 / counts[index]


def _export_error(
    model: FlashNet, temperature: float, onnx_path: Path, card_path: Path, images: np.ndarray
) -> float:
    """Max |onnxruntime − torch| on the training patches; raises if above tolerance."""
    expected = torch_probabilities(model, temperature, images)
    got = FlashClassifier.load(onnx_path, card_path).predict(images)
    error = float(np.max(np.abs(got - expected), initial=0.0))
    if error > EXPORT_TOLERANCE:
        raise RuntimeError(
            f"exported {onnx_path} disagrees with torch by {error:.2e} (> {EXPORT_TOLERANCE})"
        )
    return error
