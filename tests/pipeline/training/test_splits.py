import numpy as np
import pytest

from pipeline.training.splits import grouped_folds


def sample_groups() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    sizes = rng.integers(5, 60, 23)
    groups = np.repeat([f"video{i}" for i in range(len(sizes))], sizes)
    labels = (rng.random(len(groups)) < np.repeat(rng.random(len(sizes)), sizes)).astype(int)
    return groups, labels


@pytest.mark.parametrize("k", [2, 5, 7])
def test_folds_keep_videos_whole_and_cover_everything(k: int) -> None:
    groups, labels = sample_groups()
    folds = grouped_folds(groups, labels, k, seed=1)
    assert len(folds) == k
    tested = np.concatenate([test for _, test in folds])
    np.testing.assert_array_equal(np.sort(tested), np.arange(len(groups)))
    for train, test in folds:
        assert not set(groups[train]) & set(groups[test])
        assert len(train) + len(test) == len(groups)


def test_folds_balance_both_classes() -> None:
    groups, labels = sample_groups()
    folds = grouped_folds(groups, labels, 5)
    for cls in (0, 1):
        counts = np.array([(labels[test] == cls).sum() for _, test in folds])
        share = (labels == cls).sum() / 5
        assert np.all(np.abs(counts - share) < 0.35 * share), counts


def test_same_seed_same_folds() -> None:
    groups, labels = sample_groups()
    a, b = grouped_folds(groups, labels, 4, 3), grouped_folds(groups, labels, 4, 3)
    for (_, ta), (_, tb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(ta, tb)


def test_more_folds_than_videos_is_refused() -> None:
    with pytest.raises(ValueError, match="number of groups"):
        grouped_folds(np.array(["a", "a", "b"]), np.array([0, 1, 1]), 3)
