"""Probability calibration and threshold choice on out-of-fold predictions.

Both are fitted on predictions for recordings the predicting model did not see
(grouped cross-validation), so they reflect how the network behaves on new footage
rather than its over-confidence on its own training patches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, log_expit


@dataclass(frozen=True)
class Platt:
    """Platt scaling: ``p = sigmoid(slope * logit + intercept)``."""

    slope: float
    intercept: float

    def __call__(self, logits: np.ndarray) -> np.ndarray:
        """Calibrated probabilities of raw logits."""
        return np.asarray(expit(self.slope * np.asarray(logits) + self.intercept))


def fit_platt(logits: np.ndarray, labels: np.ndarray, weights: np.ndarray | None = None) -> Platt:
    """Slope and intercept minimising the (weighted) log loss of ``sigmoid(a z + b)``.

    Unlike temperature scaling, the intercept also moves the probability to the
    class frequency of the data it is fitted on: fit it on held-out (out-of-fold)
    predictions whose class mix is the one the probability should reflect. A slope
    kept positive preserves the ranking (AUC unchanged).
    """
    z = np.asarray(logits, dtype=np.float64)
    y = (np.asarray(labels) == 1).astype(np.float64)
    w = np.ones(len(z)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()

    def loss_and_grad(theta: np.ndarray) -> tuple[float, np.ndarray]:
        a, b = theta
        m = a * z + b
        loss = -(w * (y * log_expit(m) + (1 - y) * log_expit(-m))).sum()
        r = w * (expit(m) - y)
        return float(loss), np.array([(r * z).sum(), r.sum()])

    result = minimize(
        loss_and_grad, np.array([1.0, 0.0]), jac=True, method="L-BFGS-B",
        bounds=[(1e-3, 100.0), (-50.0, 50.0)],
    )  # fmt: skip
    return Platt(float(result.x[0]), float(result.x[1]))


def reliability(
    labels: np.ndarray, probabilities: np.ndarray, bins: int = 10
) -> list[dict[str, float | int]]:
    """Reliability diagram data: per equal-width probability bin, the number of
    patches, their mean predicted probability and the observed flash frequency
    (empty bins omitted)."""
    p = np.asarray(probabilities, dtype=np.float64)
    y = (np.asarray(labels) == 1).astype(np.float64)
    which = np.minimum((p * bins).astype(int), bins - 1)
    out: list[dict[str, float | int]] = []
    for b in range(bins):
        sel = which == b
        if sel.any():
            out.append(
                {
                    "bin": round(b / bins, 3),
                    "n": int(sel.sum()),
                    "predicted": round(float(p[sel].mean()), 4),
                    "observed": round(float(y[sel].mean()), 4),
                }
            )
    return out


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
