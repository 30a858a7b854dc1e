"""Probability calibration and threshold choice on out-of-fold predictions.

Both are fitted on predictions for recordings the predicting model did not see
(grouped cross-validation), so they reflect how the network behaves on new footage
rather than its over-confidence on its own training patches.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import expit

from pipeline.training.metrics import log_loss


def fit_temperature(logits: np.ndarray, labels: np.ndarray) -> float:
    """Temperature T minimising the log loss of ``sigmoid(logits / T)``.

    Temperature scaling (Guo et al. 2017) rescales confidence without changing the
    ranking, so AUC is unchanged. T is searched in [0.05, 20].
    """
    result = minimize_scalar(
        lambda log_t: log_loss(labels, expit(logits / np.exp(log_t))),
        bounds=(np.log(0.05), np.log(20.0)),
        method="bounded",
    )
    return float(np.exp(result.x))


def choose_threshold(
    labels: np.ndarray, probabilities: np.ndarray, weights: np.ndarray | None = None
) -> float:
    """Probability threshold with the highest (weighted) accuracy; ``p > t`` is a flash.

    Candidates are the midpoints between consecutive distinct probabilities; among
    equally accurate candidates the median one is taken rather than an extreme.
    ``weights`` (default 1) let each data source count equally whatever its size.
    """
    w = np.ones(len(labels)) if weights is None else np.asarray(weights, dtype=np.float64)
    p = np.unique(probabilities)
    cuts = np.concatenate([[0.0], (p[1:] + p[:-1]) / 2, [min(1.0, p[-1] + 1e-6)]])
    order = np.argsort(probabilities)
    sorted_p = probabilities[order]
    flash_w = np.where(labels[order] == 1, w[order], 0.0)
    background_w = w[order] - flash_w
    below = np.searchsorted(sorted_p, cuts, side="right")  # rejected: p <= cut
    flash_below = np.concatenate([[0.0], np.cumsum(flash_w)])[below]
    background_below = np.concatenate([[0.0], np.cumsum(background_w)])[below]
    correct = background_below + (flash_w.sum() - flash_below)
    best = np.flatnonzero(correct >= correct.max() * (1 - 1e-12))
    return float(cuts[best[len(best) // 2]])
