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
from pipeline.training.calibration import Platt, choose_threshold, fit_platt
from pipeline.training.dataset import PatchSet
from pipeline.training.evaluation import (
    Predictions,
    baseline_predictions,
    compare,
    comparison_dict,
    failure_montage,
    format_comparison,
    format_summary,
    held_out_summary,
    plot_reliability,
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
    figures: Path | None = None,
) -> TrainingRun:
    """Cross-validate, calibrate, train on everything and write ``out`` + its card.

    1. Grouped ``cv_folds``-fold CV (whole recordings held out; folds balanced in
       class × data source) gives an out-of-fold logit for every patch.
    2. Platt scaling is fitted to those logits (each data source weighing the same)
       and the acceptance threshold chosen on the calibrated out-of-fold
       probabilities (highest source-weighted accuracy): both come from recordings
       the predicting model never saw.
    3. The final network is trained on all patches with the same seed and exported
       with the calibration and the sigmoid inside the graph; onnxruntime's output is
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
    figures : folder for the reliability diagram and the failure montage (PNG) of the
        out-of-fold predictions; None: none written.
    """
    patches = PatchSet.concat([p.resized(input_size) for p in parts])
    folds = grouped_folds(patches.groups, patches.strata(), cv_folds, config.seed)
    logits = out_of_fold_logits(patches, folds, config, progress)
    source_weights = _per_source_weights(patches)
    platt = fit_platt(logits, patches.labels, source_weights)
    oof = platt(logits)
    threshold = choose_threshold(patches.labels, oof, source_weights)
    summary = held_out_summary(patches, oof, threshold)
    if figures is not None:
        figures.mkdir(parents=True, exist_ok=True)
        plot_reliability(
            summary, figures / f"{out.stem}-reliability.png",
            f"{out.stem}: held-out recordings ({cv_folds}-fold grouped CV)",
        )  # fmt: skip
        failure_montage(patches, oof, threshold, figures / f"{out.stem}-failures.png")
    models = [
        Predictions(f"{out.stem} (grouped CV, calibrated)", oof, threshold),
        baseline_predictions(patches, folds),
    ]
    if reference is not None:
        models.append(reference_predictions(reference, parts))
    comparison = compare(patches, models)

    model = train_model(patches, config, progress)
    export_onnx(model, platt, out, input_size)
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
            "calibration": {
                "kind": "platt",
                "slope": round(platt.slope, 6),
                "intercept": round(platt.intercept, 6),
                "fitted_on": "out-of-fold logits (recordings held out), sources weighing the same",
            },
            "threshold_rule": (
                "highest accuracy on calibrated out-of-fold probabilities, "
                "each data source weighing the same"
            ),
            "onnx_opset": ONNX_OPSET,
            "torch": torch.__version__,
            "python": platform.python_version(),
        },
        evaluation={
            "protocol": (
                f"{cv_folds}-fold grouped CV, whole source recordings held out: every "
                "figure is out-of-fold (the threshold and calibration are tuned on these "
                "same out-of-fold predictions)"
            ),
            "out_of_fold_calibration": {
                "uncalibrated": _calibration(patches.labels, expit(logits)),
                "platt_scaled": _calibration(patches.labels, oof),
            },
            "held_out_by_source": summary,
            "by_source": comparison_dict(comparison),
        },
    )
    card_path = out.with_suffix(".json")
    card.write_json(card_path)
    error = _export_error(model, platt, out, card_path, patches.images)
    title = (
        f"grouped {cv_folds}-fold CV on {len(patches)} patches from "
        f"{len(np.unique(patches.groups))} recordings (Platt slope {platt.slope:.3f}, "
        f"intercept {platt.intercept:.3f})"
    )
    report = (
        format_comparison(comparison, title)
        + "\n\n"
        + format_summary(
            summary, threshold, f"held-out recordings, calibrated, threshold {threshold:.3f}"
        )
    )
    return TrainingRun(card, report, error)


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
    model: FlashNet, platt: Platt, onnx_path: Path, card_path: Path, images: np.ndarray
) -> float:
    """Max |onnxruntime − torch| on the training patches; raises if above tolerance."""
    expected = torch_probabilities(model, platt, images)
    got = FlashClassifier.load(onnx_path, card_path).predict(images)
    error = float(np.max(np.abs(got - expected), initial=0.0))
    if error > EXPORT_TOLERANCE:
        raise RuntimeError(
            f"exported {onnx_path} disagrees with torch by {error:.2e} (> {EXPORT_TOLERANCE})"
        )
    return error
