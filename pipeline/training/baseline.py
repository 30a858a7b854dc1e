"""Baseline: hand-made contrast features + logistic regression (numpy/scipy only).

The yardstick the CNN has to beat: what a careful intensity/colour rule achieves.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Self

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, log_expit

FEATURE_NAMES = (
    "log_centre",
    "log_centre3",
    "centre3_minus_ring",
    "log_centre3_over_outer",
    "log_outer",
    "log_outer_std",
    "log_outer_gradient",
    "log_blob_area",
    "log_bright_outside",
    "centre_green_share",
    "centre_blue_share",
    "outer_blue_share",
)


def contrast_features(images: np.ndarray) -> np.ndarray:
    """Contrast, texture and colour descriptors of (N, S, S, 3) uint8 RGB patches.

    Regions are by distance r (pixels) from the centre pixel: centre 3×3, ring
    3 <= r < 6, outer r >= 8. Luminance is the RGB mean on the 0–255 scale. Blob
    area counts pixels above half the centre luminance; "bright outside" counts
    those beyond r = 4 (other glints in the patch, typical of foliage).

    Returns
    -------
    float64 (N, 12), columns named by `FEATURE_NAMES`.
    """
    x = images.astype(np.float64)
    lum = x.mean(axis=3)
    n, s = lum.shape[:2]
    c = s // 2
    yy, xx = np.mgrid[:s, :s] - c
    r = np.hypot(yy, xx)
    centre3 = np.maximum(np.abs(yy), np.abs(xx)) <= 1
    ring, outer = (r >= 3) & (r < 6), r >= 8

    flat = lum.reshape(n, -1)
    centre = lum[:, c, c]
    centre3_mean = flat[:, centre3.ravel()].mean(axis=1)
    outer_px = flat[:, outer.ravel()]
    bright = lum > 0.5 * centre[:, None, None]
    gradient = np.abs(np.diff(lum, axis=1)).mean(axis=(1, 2))
    gradient += np.abs(np.diff(lum, axis=2)).mean(axis=(1, 2))
    rgb_centre = x[:, c - 1 : c + 2, c - 1 : c + 2].mean(axis=(1, 2))
    rgb_outer = x[:, outer].mean(axis=1)
    total_centre = rgb_centre.sum(axis=1) + 1.0
    return np.column_stack(
        [
            np.log1p(centre),
            np.log1p(centre3_mean),
            centre3_mean - flat[:, ring.ravel()].mean(axis=1),
            np.log1p(centre3_mean) - np.log1p(outer_px.mean(axis=1)),
            np.log1p(outer_px.mean(axis=1)),
            np.log1p(outer_px.std(axis=1)),
            np.log1p(gradient),
            np.log1p(bright.sum(axis=(1, 2))),
            np.log1p((bright & (r > 4)).sum(axis=(1, 2))),
            rgb_centre[:, 1] / total_centre,
            rgb_centre[:, 2] / total_centre,
            rgb_outer[:, 2] / (rgb_outer.sum(axis=1) + 1.0),
        ]
    )


@dataclass(frozen=True)
class LogisticRegression:
    """L2-regularised, class-balanced logistic regression on standardised features."""

    mean: np.ndarray
    std: np.ndarray
    weights: np.ndarray
    bias: float

    @classmethod
    def fit(cls, features: np.ndarray, labels: np.ndarray, l2: float = 1e-2) -> Self:
        """Fit by L-BFGS on the class-balanced mean log loss plus ``l2 * |w|^2 / 2``."""
        mean, std = features.mean(axis=0), features.std(axis=0) + 1e-9
        z = (features - mean) / std
        y = (labels == 1).astype(np.float64)
        # each class carries half the total weight, whatever its frequency
        sample_w = np.where(y == 1, 0.5 / max(y.sum(), 1), 0.5 / max((1 - y).sum(), 1))

        def loss_and_grad(theta: np.ndarray) -> tuple[float, np.ndarray]:
            w, b = theta[:-1], theta[-1]
            margin = z @ w + b
            loss = -(sample_w * (y * log_expit(margin) + (1 - y) * log_expit(-margin))).sum()
            residual = sample_w * (expit(margin) - y)
            grad = np.append(z.T @ residual + l2 * w, residual.sum())
            return float(loss + 0.5 * l2 * w @ w), grad

        theta0 = np.zeros(z.shape[1] + 1)
        result = minimize(loss_and_grad, theta0, jac=True, method="L-BFGS-B")
        return cls(mean, std, result.x[:-1], float(result.x[-1]))

    def decision(self, features: np.ndarray) -> np.ndarray:
        """Logit of the flash class."""
        return ((features - self.mean) / self.std) @ self.weights + self.bias

    def predict_proba(self, features: np.ndarray) -> np.ndarray:
        """Flash probability (class-balanced prior)."""
        return expit(self.decision(features))
