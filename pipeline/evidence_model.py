"""The evidence model: which candidates are flashes, from every kind of evidence at once.

The rules of `pipeline.acceptance` decide with one cut per kind of evidence: the
classifier *and* 8 σ for a confident flash, a light-curve pair of 3 frames for stereo
confirmation, 40 % flicker duty, a quarter of recurrence. Each cut is where it is for
the worst case of its own kind, so a 6 σ candidate with a good patch, a clean light
curve and a match in the other camera 0.1° from its ray is rejected as surely as a
glint. The evidence model weighs all of it together (`pipeline.evidence_features`):
gradient-boosted trees (`pipeline.trees`) give each candidate a flash probability, and
the candidates at or above the model's threshold are the flashes. A model may weigh in
two passes: the second reads, beside the same evidence, what the first made of the
candidates linked to each (`pipeline.evidence_features.relayed_probabilities`: the
best frame of its light curve, its stereo match, the best frame of the light curves
that match), so a flash's faint first frames and a match whose own patch is in doubt
lean on the flash and the match as a whole.

The rules still choose the *confident* flashes that the delay and the pose are
estimated from, where purity matters more than recall; the model decides the final
set once the geometry is known. It is trained on simulated nights with ground truth
(`pipeline.training.acceptance`, ``firefly3d train-acceptance``); its card (the JSON
file itself) names the nights, the classifier whose probabilities it read, the
threshold and what it measured on nights it was not trained on. With another
classifier, or with detections made elsewhere (no probabilities), the rules decide.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import numpy as np
from numpy.typing import NDArray

from pipeline.acceptance import Evidence, Verdict
from pipeline.detections import Detections
from pipeline.evidence_features import (
    FEATURES,
    FIRST_RELAYED,
    RELAYED,
    CandidateLinks,
    StereoMatches,
    candidate_features,
    candidate_links,
    relayed_probabilities,
)
from pipeline.params import AcceptanceParams, ClassifierParams, FlickerParams, TrackingParams
from pipeline.trees import TreeEnsemble

MODELS_DIR = Path(__file__).resolve().parent / "models"
#: The shipped evidence model (`AcceptanceParams.evidence_model` "default").
DEFAULT_EVIDENCE_MODEL = MODELS_DIR / "evidence_trees.json"

BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class EvidenceModel:
    """A trained evidence model and its card.

    Attributes
    ----------
    trees : TreeEnsemble
        The classifier over rows of `features`.
    threshold : float
        Flash probability from which a candidate is accepted.
    classifier : str
        File name of the patch classifier whose probabilities it was trained on.
    card : dict
        Everything else the file says (training nights, figures; ``tracking``: the
        `TrackingParams` its candidates came from, when the card says).
    features : tuple of str
        The `FEATURES` it reads, in its trees' column order: a release may compute more
        than a model was trained on, so a new kind of evidence does not retire a model.
    second : TreeEnsemble or None
        A second pass over the same columns followed by `relayed`: the first pass's
        probabilities of the candidates linked to each (its light curve, its stereo
        match, its firefly's other flashes). None: the first pass decides (models of
        earlier releases).
    relayed : tuple of str
        The `RELAYED` columns its second pass reads, in order.
    """

    trees: TreeEnsemble
    threshold: float
    classifier: str
    card: dict[str, Any]
    features: tuple[str, ...] = FEATURES
    second: TreeEnsemble | None = None
    relayed: tuple[str, ...] = RELAYED

    def __post_init__(self) -> None:
        unknown = [name for name in self.features if name not in FEATURES]
        if unknown or not self.features or self.trees.n_features != len(self.features):
            raise ValueError(
                f"the evidence model reads features {list(self.features)} over "
                f"{self.trees.n_features} columns; this release computes {list(FEATURES)}"
            )
        unknown = [name for name in self.relayed if name not in RELAYED]
        columns = len(self.features) + len(self.relayed)
        if self.second is not None and (unknown or self.second.n_features != columns):
            raise ValueError(
                f"the evidence model's second pass reads {self.second.n_features} columns, "
                f"not its {len(self.features)} features and relayed {list(self.relayed)}; "
                f"this release relays {list(RELAYED)}"
            )

    @property
    def tracking(self) -> dict[str, Any]:
        """The `TrackingParams` fields of the nights it was trained on, as far as its card
        says (cards of earlier releases name only ``matched_sigma_px``)."""
        if "tracking" in self.card:
            return dict(self.card["tracking"])
        if "matched_sigma_px" in self.card:
            return {"matched_sigma_px": self.card["matched_sigma_px"]}
        return {}

    @classmethod
    def load(cls, path: str | Path) -> Self:
        """Read a model file (`to_json`); it must read only features of `FEATURES`."""
        data = json.loads(Path(path).read_text(encoding="utf-8"))
        card = {
            k: v
            for k, v in data.items()
            if k not in ("trees", "second_trees", "threshold", "classifier", "features", "relayed")
        }
        second = data.get("second_trees")
        try:
            return cls(
                trees=TreeEnsemble.from_dict(data["trees"]),
                threshold=float(data["threshold"]),
                classifier=str(data["classifier"]),
                card=card,
                features=tuple(data.get("features", ())),
                second=None if second is None else TreeEnsemble.from_dict(second),
                relayed=tuple(data.get("relayed", FIRST_RELAYED)),
            )
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None

    def to_json(self, path: str | Path) -> None:
        """Write the card readably, the trees' node arrays compactly, in one JSON file."""
        card = {
            **self.card,
            "features": list(self.features),
            "relayed": list(self.relayed),
            "threshold": self.threshold,
            "classifier": self.classifier,
        }
        head = json.dumps(card, indent=1)
        ensembles = {"trees": self.trees, "second_trees": self.second}
        trees = ",\n".join(
            f' "{key}": ' + json.dumps(value.to_dict(), separators=(",", ":"))
            for key, value in ensembles.items()
            if value is not None
        )
        Path(path).write_text(f"{head[:-2]},\n{trees}\n}}\n", encoding="utf-8")

    def probability(
        self, rows: NDArray[np.floating], links: CandidateLinks | None = None
    ) -> NDArray[np.float64]:
        """Flash probability of each row of `FEATURES` (the model reads its own columns).

        With the rows' `links` (both cameras' candidates, `candidate_links`) and a second
        pass, the second pass's; else the first pass's.
        """
        own = rows[:, [FEATURES.index(name) for name in self.features]]
        first = self.trees.predict_proba(own)
        if self.second is None or links is None:
            return first
        return self.second.predict_proba(
            np.column_stack([own, relayed_probabilities(first, links, self.relayed)])
        )


def evidence_model(
    params: AcceptanceParams, classifier: ClassifierParams, tracking: TrackingParams
) -> tuple[EvidenceModel | None, str | None]:
    """The evidence model a run uses, or None and why the rules decide instead.

    None without a model (``params.evidence_model`` None), when the acceptance stage is
    off, or when the patch classifier is not the one the model was trained with: its
    probabilities would mean something else. A model trained on candidates tracked with
    other `TrackingParams` (another matched filter, threshold, deblending) still decides,
    with a warning naming them (the second value): their SNRs, light curves and
    neighbours are on a slightly different scale.
    """
    if not params.enabled or params.evidence_model is None:
        return None, None
    path = DEFAULT_EVIDENCE_MODEL if params.evidence_model == "default" else params.evidence_model
    model = EvidenceModel.load(path)
    if not classifier.enabled:
        return None, "no patch classifier ran: the rules decide"
    used = Path(classifier.model).name if classifier.model else _default_classifier_name()
    if used != model.classifier:
        return None, (
            f"the evidence model was trained on {model.classifier}'s probabilities, this run "
            f"classified with {used}: the rules decide"
        )
    run = tracking.model_dump(mode="json")
    differ = sorted(name for name, value in model.tracking.items() if run.get(name, value) != value)
    if differ:
        return model, (
            "the evidence model was trained on candidates tracked with "
            + ", ".join(f"{name}={model.tracking[name]}" for name in differ)
            + ", this run tracked with "
            + ", ".join(f"{name}={run[name]}" for name in differ)
            + ": its decisions may be off"
        )
    return model, None


def _default_classifier_name() -> str:
    from pipeline.classify import DEFAULT_MODEL_NAME

    return DEFAULT_MODEL_NAME


@dataclass(frozen=True)
class Weighed:
    """The evidence model's verdict on both cameras' candidates.

    Attributes
    ----------
    probability1, probability2 : ndarray of float64
        Flash probability of each candidate.
    accepted1, accepted2 : ndarray of bool
        At or above the threshold.
    matched1, matched2 : ndarray of bool
        Matched with a candidate of the other camera (`StereoMatches`).
    """

    probability1: NDArray[np.float64]
    probability2: NDArray[np.float64]
    accepted1: BoolArray
    accepted2: BoolArray
    matched1: BoolArray
    matched2: BoolArray


def weigh(
    model: EvidenceModel,
    candidates: tuple[Detections, Detections],
    evidence: tuple[Evidence, Evidence],
    matches: StereoMatches,
    width: int,
    fps: float,
    flicker: FlickerParams,
    threshold: float | None = None,
) -> Weighed:
    """Accept the candidates whose flash probability reaches ``threshold`` (None: the
    model's)."""
    rows = candidate_features(candidates, evidence, matches, width, fps, flicker)
    cut = model.threshold if threshold is None else threshold
    p = model.probability(
        np.vstack(rows), candidate_links(candidates, evidence, matches, width, fps)
    )
    p1, p2 = p[: len(rows[0])], p[len(rows[0]) :]
    matched = [np.zeros(len(c), bool) for c in candidates]
    matched[0][matches.index1] = True
    matched[1][matches.index2] = True
    return Weighed(p1, p2, p1 >= cut, p2 >= cut, matched[0], matched[1])


def acceptance_counts(
    verdict: NDArray[np.int8], accepted: BoolArray, matched: BoolArray
) -> dict[str, int]:
    """What the evidence model did with each step-1 verdict of one camera.

    ``accepted_confident`` (the rules' confident flashes it keeps), ``accepted_stereo``
    and ``accepted_single_camera`` (the others it accepts, with or without a match in
    the other camera; ``accepted_over_rules`` of them had been rejected by an
    artifact test or the classifier), then the rejections by verdict:
    ``rejected_confident`` (confident by the rules, not by all the evidence),
    ``rejected_unconfirmed`` (doubtful), ``rejected_flicker``, ``rejected_light_curve``,
    ``rejected_classifier`` and ``rejected_recurrent``.
    """
    confident = verdict == Verdict.CONFIDENT
    tested_out = verdict > Verdict.DOUBTFUL
    rejected = ~accepted

    def n(mask: BoolArray) -> int:
        return int(np.count_nonzero(mask))

    return {
        "candidates": len(verdict),
        "accepted": n(accepted),
        "accepted_confident": n(accepted & confident),
        "accepted_stereo": n(accepted & ~confident & matched),
        "accepted_single_camera": n(accepted & ~confident & ~matched),
        "accepted_over_rules": n(accepted & tested_out),
        "rejected_confident": n(rejected & confident),
        "rejected_unconfirmed": n(rejected & (verdict == Verdict.DOUBTFUL)),
        "rejected_flicker": n(rejected & (verdict == Verdict.FLICKER)),
        "rejected_light_curve": n(rejected & (verdict == Verdict.STEADY)),
        "rejected_classifier": n(rejected & (verdict == Verdict.CLASSIFIER)),
        "rejected_recurrent": n(rejected & (verdict == Verdict.RECURRENT)),
    }
