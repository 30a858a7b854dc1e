"""Training the evidence model (`pipeline.evidence_model`) on simulated nights.

A night is a result folder of ``firefly3d process`` (made by ``eval-detection``) with
the simulated recording's ground truth. Every candidate of both cameras becomes a row
of `pipeline.evidence_features.FEATURES`, computed exactly as the accept stage computes
it (the same calibration, the same gates), and is labelled a flash when a visible true
flash of its frame lies within `pipeline.evaluate.DETECTION_TOLERANCE_PX` (the 2D
precision's definition of a true detection).

Gradient-boosted trees (scikit-learn's ``HistGradientBoostingClassifier``, a training
dependency only) are fitted, then a second pass that also reads the first pass's
probabilities of the candidates linked to each (`pipeline.evidence_features.RELAYED`):
out of fold, so that it learns how far to trust a first pass on nights that pass did not
see (stacking; the shipped first pass, trained on every night, is a little surer of
itself than those out-of-fold passes). The threshold is the one of largest F1 over out-of-fold
predictions, folds being whole seeds (the nights of one seed share their fireflies),
unless one is given (that cut moves with the mix of nights: many easy nights pull it
down, so a retrained model can keep the shipped operating point).
The trees are exported to the JSON that `pipeline.trees` evaluates.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pipeline.acceptance import Evidence, stereo_gates
from pipeline.artifacts import CALIBRATION_JSON, EVIDENCE_NPZ, candidates_name
from pipeline.detections import Detections
from pipeline.evaluate import match_detections
from pipeline.evidence_features import (
    CandidateLinks,
    candidate_features,
    candidate_links,
    relayed_probabilities,
    stereo_matches,
)
from pipeline.evidence_model import EvidenceModel
from pipeline.params import ProcessParams, TrackingParams
from pipeline.results import read_calibration
from pipeline.simulate import GroundTruth
from pipeline.training.splits import grouped_folds
from pipeline.trees import TreeEnsemble

#: Boosting settings (chosen on out-of-fold figures of the tuning nights,
#: docs/detection.md); depth 6 also bounds the evaluation's steps (`pipeline.trees`).
BOOSTING: dict[str, Any] = {
    "max_iter": 250,
    "learning_rate": 0.05,
    "max_leaf_nodes": 15,
    "max_depth": 6,
    "min_samples_leaf": 40,
    "l2_regularization": 1.0,
    "early_stopping": False,
}


@dataclass(frozen=True)
class Night:
    """The labelled feature rows of one simulated night (both cameras).

    Attributes
    ----------
    name : str
        ``<scenario> s<seed> <width>px <fps>fps``.
    kind : str
        The same without the seed: what the out-of-fold figures are pooled by.
    seed : int
    rows : ndarray, shape (N, len(FEATURES))
    is_flash : ndarray of bool, shape (N,)
    links : CandidateLinks
        The rows' light curves and stereo partners (`candidate_links`).
    """

    name: str
    kind: str
    seed: int
    rows: NDArray[np.float64]
    is_flash: NDArray[np.bool_]
    links: CandidateLinks


def night_rows(results: Path, truth: GroundTruth, params: ProcessParams) -> Night:
    """Feature rows and labels of every candidate of a result folder."""
    calibration = read_calibration(results / CALIBRATION_JSON)
    candidates = tuple(Detections.from_npz(results / candidates_name(c)) for c in (1, 2))
    evidence = tuple(Evidence.load(results / EVIDENCE_NPZ.format(camera=c)) for c in (1, 2))
    gates = stereo_gates(params.acceptance, params.triangulation)
    pair = (candidates[0], candidates[1])
    matches = stereo_matches(
        pair,
        calibration.delay_frames,
        calibration.pose,
        calibration.width,
        truth.separation_m,
        gates,
    )
    rows = candidate_features(
        pair,
        (evidence[0], evidence[1]),
        matches,
        calibration.width,
        calibration.fps,
        params.flicker,
    )
    labels = [match_detections(candidates[c], truth, c + 1).true_detection for c in (0, 1)]
    kind = f"{truth.scenario} {truth.width}px {truth.fps:g}fps"
    name = f"{truth.scenario} s{truth.seed} {truth.width}px {truth.fps:g}fps"
    links = candidate_links(
        pair, (evidence[0], evidence[1]), matches, calibration.width, calibration.fps
    )
    return Night(name, kind, truth.seed, np.vstack(rows), np.concatenate(labels), links)


def run_params(results: Path) -> ProcessParams:
    """The parameters a result folder was made with (``eval-params.json``), else the
    defaults."""
    stamp = results / "eval-params.json"
    if stamp.is_file():
        return ProcessParams.model_validate(json.loads(stamp.read_text(encoding="utf-8")))
    return ProcessParams()


def common_tracking(params: Sequence[ProcessParams]) -> TrackingParams:
    """The one `TrackingParams` all the runs tracked with.

    A model learns the SNRs, light curves and neighbours of one tracking's candidates
    (its matched filter, its thresholds, whether crowded flashes are deblended), so runs
    tracked differently are refused (ValueError, naming the fields that differ).
    """
    if not params:
        raise ValueError("no runs: a model is trained on the candidates of at least one")
    first = params[0].tracking.model_dump(mode="json")
    differ: dict[str, list[Any]] = {}
    for other in params[1:]:
        for name, value in other.tracking.model_dump(mode="json").items():
            if value != first[name]:
                differ.setdefault(name, [first[name]]).append(value)
    if differ:
        fields = "; ".join(
            f"{name} {sorted(set(map(str, values)))}" for name, values in sorted(differ.items())
        )
        raise ValueError(
            f"the runs tracked differently ({fields}); a model is trained on the candidates "
            "of one tracking"
        )
    return params[0].tracking


def to_ensemble(model: Any) -> TreeEnsemble:
    """A fitted binary ``HistGradientBoostingClassifier`` as a `TreeEnsemble`."""
    nodes = [predictor.nodes for (predictor,) in model._predictors]
    offsets = np.cumsum([0, *(len(n) for n in nodes[:-1])])
    every = np.concatenate(nodes)
    shift = np.repeat(offsets, [len(n) for n in nodes])
    leaf = every["is_leaf"].astype(bool)
    index = np.arange(len(every))
    if np.any(every["is_categorical"][~leaf]):
        raise ValueError("categorical splits are not supported")
    return TreeEnsemble(
        feature=np.where(leaf, -1, every["feature_idx"]).astype(np.intp),
        threshold=np.where(leaf, 0.0, every["num_threshold"]),
        missing_left=every["missing_go_to_left"].astype(bool),
        left=np.where(leaf, index, every["left"].astype(np.intp) + shift),
        right=np.where(leaf, index, every["right"].astype(np.intp) + shift),
        value=np.where(leaf, every["value"], 0.0),
        roots=offsets.astype(np.intp),
        baseline=float(np.ravel(model._baseline_prediction)[0]),
        n_features=int(model.n_features_in_),
    )


def fit_trees(rows: NDArray[np.float64], is_flash: NDArray[np.bool_], seed: int) -> TreeEnsemble:
    from sklearn.ensemble import HistGradientBoostingClassifier

    model = HistGradientBoostingClassifier(**BOOSTING, random_state=seed)
    # scikit-learn cannot bin a column without a single value (nights where no light
    # curve has a neighbour); it has nothing to split on either way.
    empty = np.isnan(rows).all(axis=0)
    return to_ensemble(model.fit(np.where(empty, 0.0, rows), is_flash))


def best_f1_threshold(probability: NDArray[np.float64], is_flash: NDArray[np.bool_]) -> float:
    """The probability cut of largest F1 (ties: the higher cut)."""
    order = np.argsort(-probability, kind="stable")
    true = np.cumsum(is_flash[order])
    f1 = 2 * true / (np.arange(1, len(order) + 1) + is_flash.sum())
    # Only cut between distinct probabilities.
    distinct = np.r_[probability[order][1:] < probability[order][:-1], True]
    best = np.flatnonzero(distinct)[np.argmax(f1[distinct])]
    return float(probability[order][best])


def equal_false_threshold(
    probability: NDArray[np.float64], is_flash: NDArray[np.bool_], n_false: int
) -> float:
    """The lowest probability cut that accepts at most `n_false` of the false rows."""
    false = np.sort(probability[~is_flash])[::-1]
    if n_false >= len(false):
        return 0.0
    return float(np.nextafter(false[n_false], np.inf))


def operating_point(
    probability: NDArray[np.float64], is_flash: NDArray[np.bool_], threshold: float
) -> dict[str, float | int]:
    accepted = probability >= threshold
    true = int(np.count_nonzero(accepted & is_flash))
    n = int(np.count_nonzero(accepted))
    flashes = int(np.count_nonzero(is_flash))
    return {
        "accepted": n,
        "true": true,
        "precision": true / n if n else float("nan"),
        "recall_of_candidates": true / flashes if flashes else float("nan"),
    }


def train(
    nights: Sequence[Night],
    classifier: str,
    tracking: TrackingParams,
    seed: int = 0,
    threshold: float | None = None,
    folds: int = 4,
    first_pass_cut: float | None = None,
) -> tuple[EvidenceModel, dict[str, Any]]:
    """Fit the evidence model's two passes on `nights`; its threshold and the figures of
    its card come from the second pass's out-of-fold predictions (folds of whole seeds).

    The threshold is `threshold` if given; else, with `first_pass_cut`, the lowest cut at
    which the second pass accepts no more false candidates than the first pass alone at
    `first_pass_cut` (a retrained model keeps an operating point's false count); else
    the cut of largest F1.

    `classifier` (file name) and `tracking` (the nights' `TrackingParams`) say where the
    nights' candidates and probabilities came from; the card records both.

    Returns
    -------
    (EvidenceModel, dict)
        The model, and the out-of-fold figures per kind of night (scenario, width, frame
        rate) at its threshold (also in the model's card).
    """
    rows = np.vstack([n.rows for n in nights])
    is_flash = np.concatenate([n.is_flash for n in nights])
    seeds = np.concatenate([np.full(len(n.is_flash), n.seed) for n in nights])
    kind = np.concatenate([np.full(len(n.is_flash), n.kind) for n in nights])
    links = stacked_links([n.links for n in nights])
    split = grouped_folds(seeds, is_flash, min(folds, len(set(seeds))), seed)
    first = out_of_fold(rows, is_flash, split, seed)
    relayed = np.column_stack([rows, relayed_probabilities(first, links)])
    second = out_of_fold(relayed, is_flash, split, seed)
    if threshold is not None:
        chosen_by = "given"
    elif first_pass_cut is not None:
        chosen_by = f"the first pass's out-of-fold false count at {first_pass_cut:g}"
        kept = operating_point(first, is_flash, first_pass_cut)
        n_false = int(kept["accepted"]) - int(kept["true"])
        threshold = equal_false_threshold(second, is_flash, n_false)
    else:
        chosen_by = "largest out-of-fold F1"
        threshold = best_f1_threshold(second, is_flash)
    figures = {
        name: operating_point(second[kind == name], is_flash[kind == name], threshold)
        for name in sorted(set(kind))
    }
    card = {
        "name": "evidence_trees",
        "kind": "gradient-boosted trees over pipeline.evidence_features.FEATURES, then a "
        "second pass over them and RELAYED",
        "boosting": BOOSTING,
        "seed": seed,
        "tracking": tracking.model_dump(mode="json"),
        "trained_on": [n.name for n in nights],
        "n_rows": len(rows),
        "n_flashes": int(is_flash.sum()),
        "threshold_chosen_by": chosen_by,
        "out_of_fold_at_threshold": figures,
        "first_pass_out_of_fold_at_threshold": operating_point(first, is_flash, threshold),
    }
    model = EvidenceModel(
        fit_trees(rows, is_flash, seed),
        threshold,
        classifier,
        card,
        second=fit_trees(relayed, is_flash, seed),
    )
    return model, figures


def out_of_fold(
    rows: NDArray[np.float64],
    is_flash: NDArray[np.bool_],
    split: Sequence[tuple[NDArray[np.intp], NDArray[np.intp]]],
    seed: int,
) -> NDArray[np.float64]:
    """Each row's flash probability from trees fitted on the other folds' rows."""
    probability = np.full(len(rows), np.nan)
    for train_rows, test_rows in split:
        trees = fit_trees(rows[train_rows], is_flash[train_rows], seed)
        probability[test_rows] = trees.predict_proba(rows[test_rows])
    return probability


def stacked_links(links: Sequence[CandidateLinks]) -> CandidateLinks:
    """The links of several nights' rows stacked in order (labels and rows shifted)."""
    sizes = np.array([len(n.partner) for n in links], dtype=np.intp)
    row_offset = np.cumsum(np.r_[0, sizes[:-1]])
    curves = [int(n.light_curve.max()) + 1 if len(n.light_curve) else 0 for n in links]
    curve_offset = np.cumsum(np.r_[0, curves[:-1]])
    return CandidateLinks(
        light_curve=np.concatenate(
            [n.light_curve + c for n, c in zip(links, curve_offset, strict=True)]
        ).astype(np.intp),
        partner=np.concatenate(
            [
                np.where(n.partner >= 0, n.partner + r, -1)
                for n, r in zip(links, row_offset, strict=True)
            ]
        ).astype(np.intp),
        # Each night's two recordings get sequences of their own.
        sequence=np.concatenate([n.sequence + 2 * k for k, n in enumerate(links)]).astype(np.intp),
        time_s=np.concatenate([n.time_s for n in links]),
        bearing=np.vstack([n.bearing for n in links]).reshape(-1, 3),
    )
