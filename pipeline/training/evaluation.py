"""Evaluation reports: a classifier against the baselines, per data source and recording.

Every figure is reported separately for each data source (e.g. the real phone
patches and the simulated ones), because a pooled AUC would mostly measure how well
the model tells the sources apart. numpy/scipy only, so ``eval-classifier`` runs
without torch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.classify import FlashClassifier
from pipeline.training.baseline import LogisticRegression, contrast_features
from pipeline.training.calibration import choose_threshold
from pipeline.training.dataset import PatchSet
from pipeline.training.metrics import Scores, score, score_by_group

BASELINE_NAME = "contrast features + logistic regression"


@dataclass(frozen=True)
class Predictions:
    """One model's flash probabilities for every patch of a set (NaN: not applicable)."""

    name: str
    probabilities: np.ndarray
    threshold: float


@dataclass(frozen=True)
class ModelResult:
    """One model's predictions on a patch set, scored at its threshold."""

    name: str
    threshold: float
    overall: Scores
    per_group: dict[str, Scores]

    @classmethod
    def of(cls, patches: PatchSet, predictions: Predictions) -> ModelResult:
        """Score ``predictions`` of ``patches`` overall and per source recording."""
        p, t = predictions.probabilities, predictions.threshold
        return cls(
            predictions.name,
            t,
            score(patches.labels, p, t),
            score_by_group(patches.labels, p, patches.groups, t),
        )

    def as_dict(self) -> dict[str, object]:
        """For the model card: overall figures and per-recording ones."""
        return {
            "threshold": round(self.threshold, 4),
            **self.overall.as_dict(),
            "per_recording": {g: s.as_dict() for g, s in self.per_group.items()},
        }


def baseline_predictions(
    patches: PatchSet, folds: Sequence[tuple[np.ndarray, np.ndarray]]
) -> Predictions:
    """Contrast features + logistic regression, out of fold under ``folds``.

    The threshold is the most accurate one on these out-of-fold probabilities.
    """
    features = contrast_features(patches.images)
    p = np.full(len(patches), np.nan)
    for train, test in folds:
        p[test] = LogisticRegression.fit(features[train], patches.labels[train]).predict_proba(
            features[test]
        )
    return Predictions(f"{BASELINE_NAME} (grouped CV)", p, choose_threshold(patches.labels, p))


def reference_predictions(reference: FlashClassifier, parts: Sequence[PatchSet]) -> Predictions:
    """A published model's probabilities on the data sources whose patches are at
    least its input size (centre-cropped to it); NaN elsewhere, since edge-padding a
    small patch shows the model something it never saw."""
    size = reference.input_size
    p = np.concatenate(
        [
            reference.predict(part.resized(size).images)
            if part.size >= size
            else np.full(len(part), np.nan)
            for part in parts
        ]
    )
    return Predictions(f"reference {reference.card.name}", p, reference.threshold)


def compare(patches: PatchSet, models: Sequence[Predictions]) -> dict[str, list[ModelResult]]:
    """Each model's results on each data source (models without predictions there skipped)."""
    out = {}
    for source in np.unique(patches.sources):
        rows = np.flatnonzero(patches.sources == source)
        part = patches.subset(rows)
        out[str(source)] = [
            ModelResult.of(part, Predictions(m.name, m.probabilities[rows], m.threshold))
            for m in models
            if not np.isnan(m.probabilities[rows]).any()
        ]
    return out


def format_comparison(comparison: dict[str, list[ModelResult]], title: str) -> str:
    """`format_report` for each data source, one after the other."""
    return "\n\n".join(
        format_report(results, f"{title} | source: {source}")
        for source, results in comparison.items()
    )


def comparison_dict(comparison: dict[str, list[ModelResult]]) -> dict[str, object]:
    """For the model card: ``{source: {model: figures}}``."""
    return {s: {r.name: r.as_dict() for r in results} for s, results in comparison.items()}


def format_report(results: Sequence[ModelResult], title: str) -> str:
    """Text report: one summary line per model, then a per-recording table."""
    lines = [title, ""]
    header = f"{'model':58s} {'thr':>5s} {'AUC':>6s} {'acc':>6s} {'prec':>6s} {'recall':>6s}"
    lines += [header, "-" * len(header)]
    for r in results:
        s = r.overall
        lines.append(
            f"{r.name[:58]:58s} {r.threshold:5.3f} {s.auc:6.4f} {s.accuracy:6.4f} "
            f"{s.precision:6.4f} {s.recall:6.4f}"
        )
    lines += ["", "per source recording (accuracy; /AUC where both classes are present):"]
    names = " ".join(f"{f'model {i + 1}':>16s}" for i in range(len(results)))
    lines.append(f"{'recording':24s} {'n':>5s} {'flash':>5s} {names}")
    for group in results[0].per_group:
        first = results[0].per_group[group]
        cells = " ".join(_cell(r.per_group[group]) for r in results)
        lines.append(f"{group[:24]:24s} {first.n:5d} {first.n_flash:5d} {cells}")
    lines.append("models: " + "; ".join(f"{i + 1} = {r.name}" for i, r in enumerate(results)))
    return "\n".join(lines)


def _cell(s: Scores) -> str:
    auc = "" if np.isnan(s.auc) else f"/{s.auc:.3f}"
    return f"{f'{s.accuracy:.3f}{auc}':>16s}"
