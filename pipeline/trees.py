"""Gradient-boosted decision trees, evaluated with numpy: a model that is data.

A binary classifier of ``T`` regression trees: the log-odds of a row is a baseline plus
the value of the leaf it reaches in every tree. At a split node the row goes left when
its feature is at most the node's threshold, and a missing feature (NaN) goes the side
the node learnt for missing values. This is the prediction rule of scikit-learn's
``HistGradientBoostingClassifier`` on raw (unbinned) features, so a model trained there
(`pipeline.training.acceptance`) is exported to JSON and evaluated here without
scikit-learn, as the patch classifier is evaluated with onnxruntime without PyTorch.

Evaluation walks every tree at once for a block of rows: one vectorised step per level
of the deepest tree, over flat (row, tree) arrays.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import numpy as np
from numpy.typing import NDArray

#: Rows evaluated at once (memory: rows × trees node indices; small blocks stay in cache).
BLOCK_ROWS = 2048


@dataclass(frozen=True)
class TreeEnsemble:
    """The nodes of all trees, concatenated (tree ``t``'s root at ``roots[t]``).

    Attributes
    ----------
    feature : ndarray of intp
        Feature column tested at each split node (-1 at leaves).
    threshold : ndarray of float64
        Go left when the feature is at most this.
    missing_left : ndarray of bool
        Where a missing (NaN) feature goes.
    left, right : ndarray of intp
        Global indices of the children (a leaf points at itself).
    value : ndarray of float64
        Leaf values (log-odds contributions); 0 at split nodes.
    roots : ndarray of intp
        Index of each tree's root.
    baseline : float
        Log-odds before any tree.
    n_features : int
        Columns a row must have.
    """

    feature: NDArray[np.intp]
    threshold: NDArray[np.float64]
    missing_left: NDArray[np.bool_]
    left: NDArray[np.intp]
    right: NDArray[np.intp]
    value: NDArray[np.float64]
    roots: NDArray[np.intp]
    baseline: float
    n_features: int

    def __post_init__(self) -> None:
        n = len(self.feature)
        for name in ("threshold", "missing_left", "left", "right", "value"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"tree nodes: column {name!r} must have {n} entries")
        leaf = self.feature < 0
        if np.any(self.feature >= self.n_features):
            raise ValueError("tree nodes test a feature beyond n_features")
        children = np.concatenate([self.left[~leaf], self.right[~leaf], self.roots])
        if np.any((children < 0) | (children >= n)):
            raise ValueError("tree nodes point outside the ensemble")

    @property
    def depth(self) -> int:
        """Levels of the deepest tree (0 for trees that are single leaves)."""
        depth = 0
        frontier = self.roots
        while True:
            splits = frontier[self.feature[frontier] >= 0]
            if len(splits) == 0:
                return depth
            depth += 1
            if depth > len(self.feature):
                raise ValueError("tree nodes form a cycle")
            frontier = np.concatenate([self.left[splits], self.right[splits]])

    def decision_function(self, rows: NDArray[np.floating]) -> NDArray[np.float64]:
        """Log-odds of each row, shape (N,), of rows of shape (N, n_features)."""
        rows = np.asarray(rows, dtype=np.float64)
        if rows.ndim != 2 or rows.shape[1] != self.n_features:
            raise ValueError(f"rows must have shape (N, {self.n_features}), got {rows.shape}")
        # Leaves become nodes that keep every row where it is: feature 0 at +inf, both
        # children themselves, missing values to the left (itself).
        leaf = self.feature < 0
        feature = np.where(leaf, 0, self.feature)
        threshold = np.where(leaf, np.inf, self.threshold)
        missing_left = self.missing_left | leaf
        depth = self.depth
        out = np.empty(len(rows))
        for start in range(0, len(rows), BLOCK_ROWS):
            block = np.ascontiguousarray(rows[start : start + BLOCK_ROWS]).ravel()
            n = len(block) // self.n_features
            # One entry per (row, tree), flat: the row's offset in `block` and its node.
            offset = np.repeat(np.arange(n) * self.n_features, len(self.roots))
            node = np.tile(self.roots, n)
            for _ in range(depth):
                x = block[offset + feature[node]]
                left = (x <= threshold[node]) | (np.isnan(x) & missing_left[node])
                node = np.where(left, self.left[node], self.right[node])
            out[start : start + n] = self.baseline + self.value[node].reshape(n, -1).sum(axis=1)
        return out

    def predict_proba(self, rows: NDArray[np.floating]) -> NDArray[np.float64]:
        """Probability of the positive class of each row, shape (N,)."""
        return 1.0 / (1.0 + np.exp(-self.decision_function(rows)))

    # -- JSON ---------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (`from_dict` reads it back exactly)."""
        return {
            "baseline": self.baseline,
            "n_features": self.n_features,
            "roots": self.roots.tolist(),
            "feature": self.feature.tolist(),
            "threshold": [float(t) for t in self.threshold],
            "missing_left": self.missing_left.astype(int).tolist(),
            "left": self.left.tolist(),
            "right": self.right.tolist(),
            "value": [float(v) for v in self.value],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Self:
        return cls(
            feature=np.asarray(data["feature"], np.intp),
            threshold=np.asarray(data["threshold"], np.float64),
            missing_left=np.asarray(data["missing_left"], bool),
            left=np.asarray(data["left"], np.intp),
            right=np.asarray(data["right"], np.intp),
            value=np.asarray(data["value"], np.float64),
            roots=np.asarray(data["roots"], np.intp),
            baseline=float(data["baseline"]),
            n_features=int(data["n_features"]),
        )

    @classmethod
    def load(cls, path: str | Path) -> Self:
        return cls.from_dict(json.loads(Path(path).read_text(encoding="utf-8")))
