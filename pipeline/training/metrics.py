"""Classification metrics for flash probabilities (numpy/scipy only)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.stats import rankdata

_EPS = 1e-7


def roc_auc(labels: np.ndarray, scores: np.ndarray) -> float:
    """Area under the ROC curve, via the Mann–Whitney U statistic.

    Equals the probability that a random positive scores above a random negative,
    ties counting one half. NaN when either class is absent.
    """
    positive = np.asarray(labels) == 1
    n_pos = int(positive.sum())
    n_neg = len(positive) - n_pos
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(scores)
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def log_loss(labels: np.ndarray, probabilities: np.ndarray) -> float:
    """Mean negative log-likelihood (nats) of the labels under the probabilities."""
    p = np.clip(probabilities, _EPS, 1 - _EPS)
    return float(-np.mean(np.where(labels == 1, np.log(p), np.log1p(-p))))


def expected_calibration_error(
    labels: np.ndarray, probabilities: np.ndarray, bins: int = 10
) -> float:
    """Mean |observed flash rate − mean probability| over equal-width probability bins,
    weighted by the bin's share of samples."""
    which = np.minimum((np.asarray(probabilities) * bins).astype(int), bins - 1)
    gap = np.bincount(which, weights=labels - probabilities, minlength=bins)
    return float(np.abs(gap).sum() / max(len(labels), 1))


@dataclass(frozen=True)
class Scores:
    """Figures of one set of predictions at a threshold (probability > threshold = flash)."""

    n: int
    n_flash: int
    auc: float
    accuracy: float
    precision: float
    recall: float
    log_loss: float

    def as_dict(self) -> dict[str, float | int]:
        """The figures rounded for reports and model cards."""
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}


def score(labels: np.ndarray, probabilities: np.ndarray, threshold: float) -> Scores:
    """AUC, accuracy and precision/recall of flashes at ``threshold``.

    Precision is NaN when nothing is accepted, recall NaN when there are no flashes.
    """
    labels = np.asarray(labels)
    accepted = np.asarray(probabilities) > threshold
    flash = labels == 1
    tp = int((accepted & flash).sum())
    return Scores(
        n=len(labels),
        n_flash=int(flash.sum()),
        auc=roc_auc(labels, probabilities),
        accuracy=float((accepted == flash).mean()) if len(labels) else float("nan"),
        precision=tp / int(accepted.sum()) if accepted.any() else float("nan"),
        recall=tp / int(flash.sum()) if flash.any() else float("nan"),
        log_loss=log_loss(labels, probabilities) if len(labels) else float("nan"),
    )


def score_by_group(
    labels: np.ndarray, probabilities: np.ndarray, groups: np.ndarray, threshold: float
) -> dict[str, Scores]:
    """`score` per group (source recording), in sorted group order."""
    return {
        str(g): score(labels[groups == g], probabilities[groups == g], threshold)
        for g in np.unique(groups)
    }
