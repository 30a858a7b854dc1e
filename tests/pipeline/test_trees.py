"""Gradient-boosted trees evaluated with numpy (pipeline.trees)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.trees import BLOCK_ROWS, TreeEnsemble


def _stump_and_tree() -> TreeEnsemble:
    """Tree 0: x0 <= 1 ? -1 : +2 (missing left). Tree 1: x1 <= 0 ? (x0 <= 3 ? 0.5 : 1.5)
    : -0.25 (missing right)."""
    return TreeEnsemble(
        feature=np.array([0, -1, -1, 1, 0, -1, -1, -1]),
        threshold=np.array([1.0, 0, 0, 0.0, 3.0, 0, 0, 0]),
        missing_left=np.array([1, 0, 0, 0, 1, 0, 0, 0], bool),
        left=np.array([1, 1, 2, 4, 5, 5, 6, 7]),
        right=np.array([2, 1, 2, 7, 6, 5, 6, 7]),
        value=np.array([0, -1.0, 2.0, 0, 0, 0.5, 1.5, -0.25]),
        roots=np.array([0, 3]),
        baseline=0.1,
        n_features=2,
    )


def test_rows_follow_thresholds_and_missing_values_to_their_leaves() -> None:
    trees = _stump_and_tree()
    rows = np.array(
        [
            [0.5, -1.0],  # left, then left-left: -1 + 0.5
            [1.0, -1.0],  # at the threshold goes left: same
            [2.0, -1.0],  # right (+2), then x0 <= 3: +0.5
            [4.0, -1.0],  # +2, x0 > 3: +1.5
            [4.0, 5.0],  # +2, x1 > 0: -0.25
            [np.nan, -1.0],  # missing x0: left in both trees: -1 + 0.5
            [2.0, np.nan],  # missing x1 goes right: +2 - 0.25
        ]
    )
    want = 0.1 + np.array([-0.5, -0.5, 2.5, 3.5, 1.75, -0.5, 1.75])
    np.testing.assert_allclose(trees.decision_function(rows), want)
    np.testing.assert_allclose(trees.predict_proba(rows), 1 / (1 + np.exp(-want)))
    assert trees.depth == 2


def test_blocks_give_the_same_answer_as_one_pass() -> None:
    trees = _stump_and_tree()
    rows = np.random.default_rng(0).normal(0, 3, (2 * BLOCK_ROWS + 17, 2))
    whole = trees.decision_function(rows)
    parts = np.concatenate(
        [trees.decision_function(rows[i : i + 100]) for i in range(0, len(rows), 100)]
    )
    np.testing.assert_array_equal(whole, parts)


def test_json_round_trip_is_exact(tmp_path) -> None:
    trees = _stump_and_tree()
    path = tmp_path / "trees.json"
    import json

    path.write_text(json.dumps(trees.to_dict()))
    back = TreeEnsemble.load(path)
    rows = np.random.default_rng(1).normal(0, 3, (50, 2))
    np.testing.assert_array_equal(back.decision_function(rows), trees.decision_function(rows))


def test_malformed_ensembles_and_rows_are_refused() -> None:
    good = _stump_and_tree()
    with pytest.raises(ValueError, match="outside"):
        TreeEnsemble(**{**good.__dict__, "left": np.array([1, 1, 2, 4, 50, 5, 6, 7])})
    with pytest.raises(ValueError, match="beyond n_features"):
        TreeEnsemble(**{**good.__dict__, "n_features": 1})
    cycle = TreeEnsemble(**{**good.__dict__, "left": np.array([1, 1, 2, 3, 5, 5, 6, 7])})
    with pytest.raises(ValueError, match="cycle"):
        cycle.decision_function(np.zeros((1, 2)))
    with pytest.raises(ValueError, match="shape"):
        good.decision_function(np.zeros((3, 5)))


def test_a_scikit_learn_model_is_exported_exactly() -> None:
    from sklearn.ensemble import HistGradientBoostingClassifier

    from pipeline.training.acceptance import BOOSTING, to_ensemble

    rng = np.random.default_rng(2)
    rows = rng.normal(size=(2000, 4))
    rows[rng.random(rows.shape) < 0.1] = np.nan  # trees learn where missing values go
    label = np.nan_to_num(rows[:, 0]) + np.nan_to_num(rows[:, 1]) ** 2 + rng.normal(0, 0.5, 2000)
    model = HistGradientBoostingClassifier(**{**BOOSTING, "max_iter": 40}, random_state=0)
    model.fit(rows, label > 1)
    trees = to_ensemble(model)
    test = rng.normal(size=(3000, 4))
    test[rng.random(test.shape) < 0.1] = np.nan
    np.testing.assert_allclose(
        trees.predict_proba(test), model.predict_proba(test)[:, 1], atol=1e-12
    )
