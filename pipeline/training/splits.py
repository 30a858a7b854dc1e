"""Grouped (leave-recordings-out) cross-validation splits.

Patches of one recording share camera, scene, exposure and compression, so a random
patch split measures memory of recordings, not generalisation to new ones. Every split
here keeps each group (source recording) whole on one side.
"""

from __future__ import annotations

import numpy as np


def grouped_folds(
    groups: np.ndarray, strata: np.ndarray, k: int, seed: int = 0
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split into ``k`` folds of whole groups with balanced stratum counts.

    Groups are placed largest first (ties in a seeded random order), each into the
    fold whose per-stratum counts stay closest to an equal share (least sum of
    squared relative loads), a stratified variant of group k-fold.

    Parameters
    ----------
    groups : (N,) group of each sample (e.g. source video id).
    strata : (N,) what to balance across folds: the class, or class × data source.
    k : number of folds, 2 <= k <= number of groups.
    seed : order of groups of equal size.

    Returns
    -------
    list of ``k`` (train_index, test_index) integer arrays; every sample is in exactly
    one test fold and no group is on both sides of any split.
    """
    names, group_of = np.unique(groups, return_inverse=True)
    if not 2 <= k <= len(names):
        raise ValueError(f"cv folds must be between 2 and the number of groups ({len(names)})")
    classes, class_of = np.unique(strata, return_inverse=True)
    counts = np.zeros((len(names), len(classes)))
    np.add.at(counts, (group_of, class_of), 1)
    share = counts.sum(axis=0) / k

    order = np.random.default_rng(seed).permutation(len(names))
    order = order[np.argsort(-counts[order].sum(axis=1), kind="stable")]
    load = np.zeros((k, len(classes)))
    fold_of_group = np.empty(len(names), dtype=int)
    for g in order:  # a handful of groups: greedy placement, not a hot path
        cost = (((load + counts[g]) / share) ** 2).sum(axis=1) - ((load / share) ** 2).sum(axis=1)
        fold = int(np.argmin(cost))
        fold_of_group[g] = fold
        load[fold] += counts[g]

    fold_of_sample = fold_of_group[group_of]
    return [
        (np.flatnonzero(fold_of_sample != f), np.flatnonzero(fold_of_sample == f)) for f in range(k)
    ]
