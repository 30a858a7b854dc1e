"""The evidence model: the final decision from all the evidence (pipeline.evidence_model)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.acceptance import Evidence, Verdict, spot_chains, steady_frames
from pipeline.classify import DEFAULT_MODEL_NAME
from pipeline.detections import Detections
from pipeline.evidence_features import FEATURES, FIRST_RELAYED, RELAYED, stereo_matches
from pipeline.evidence_model import (
    DEFAULT_EVIDENCE_MODEL,
    EvidenceModel,
    acceptance_counts,
    evidence_model,
    weigh,
)
from pipeline.geometry import Pose, bearing_to_pixel
from pipeline.params import (
    AcceptanceParams,
    ClassifierParams,
    FlickerParams,
    TrackingParams,
    TriangulationParams,
)
from pipeline.trees import TreeEnsemble
from tests.pipeline.links_factory import links_apart

WIDTH, FPS, SEPARATION = 640, 30.0, 1.5
POSE = Pose(np.eye(3), [1.0, 0.0, 0.0])


def test_the_shipped_model_reads_this_releases_features() -> None:
    model = EvidenceModel.load(DEFAULT_EVIDENCE_MODEL)
    assert set(model.features) <= set(FEATURES)
    assert model.trees.n_features == len(model.features)
    assert 0 < model.threshold < 1 and model.classifier == DEFAULT_MODEL_NAME
    assert model.card["trained_on"] and model.card["out_of_fold_at_threshold"]
    assert model.trees.depth <= 6


def _stump(column: int, n_features: int, cut: float) -> TreeEnsemble:
    """One split: left (log-odds -2) at or below `cut` on `column`, right +2."""
    return TreeEnsemble(
        feature=np.array([column, -1, -1]),
        threshold=np.array([cut, 0.0, 0.0]),
        missing_left=np.ones(3, bool),
        left=np.array([1, 1, 2]),
        right=np.array([2, 1, 2]),
        value=np.array([0.0, -2.0, 2.0]),
        roots=np.array([0]),
        baseline=0.0,
        n_features=n_features,
    )


def test_a_model_reads_its_own_columns_of_the_features() -> None:
    # One split on the model's first column, which is FEATURES' "probability": a model
    # trained before the other features existed.
    model = EvidenceModel(_stump(0, 1, 0.5), 0.5, DEFAULT_MODEL_NAME, {}, features=("probability",))
    rows = np.full((3, len(FEATURES)), 0.2)
    rows[1, [i for i, name in enumerate(FEATURES) if name != "probability"]] = 50.0
    rows[2, FEATURES.index("probability")] = 0.9
    p = model.probability(rows)
    assert p[1] == p[0]  # columns it does not read
    assert p[0] < 0.5 < p[2]  # the one it reads


def test_a_model_of_other_features_is_refused(tmp_path) -> None:
    data = json.loads(DEFAULT_EVIDENCE_MODEL.read_text())
    unknown = dict(data, features=[*data["features"][:-1], "moon_phase"])
    fewer = dict(data, features=data["features"][:-1])  # its trees read one more column
    for name, bad in (("unknown", unknown), ("fewer", fewer)):
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match="reads features"):
            EvidenceModel.load(path)


def test_a_model_written_and_read_back_keeps_its_features(tmp_path) -> None:
    model = EvidenceModel.load(DEFAULT_EVIDENCE_MODEL)
    model.to_json(tmp_path / "copy.json")
    copy = EvidenceModel.load(tmp_path / "copy.json")
    assert copy.features == model.features and copy.threshold == model.threshold
    rows = np.random.default_rng(0).normal(size=(20, len(FEATURES)))
    np.testing.assert_array_equal(copy.probability(rows), model.probability(rows))


def test_a_second_pass_reads_what_the_first_thought_of_the_linked_candidates(tmp_path) -> None:
    # First pass: probability > 0.5. Second: the best first-pass probability along
    # the light curve (the relayed column after the one feature) > 0.5.
    model = EvidenceModel(
        _stump(0, 1, 0.5),
        0.5,
        DEFAULT_MODEL_NAME,
        {},
        features=("probability",),
        second=_stump(1 + RELAYED.index("light_curve_flash_probability"), 1 + len(RELAYED), 0.5),
    )
    rows = np.full((3, len(FEATURES)), 0.2)
    rows[2, FEATURES.index("probability")] = 0.9
    one_curve = links_apart(np.array([0, 0, 1]), np.full(3, -1))
    apart = links_apart(np.array([0, 1, 2]), np.full(3, -1))
    first = model.probability(rows)
    assert first[0] < 0.5 < first[2]
    # Row 1 shares row 0's dim light curve; sharing row 2's, both are lifted.
    lifted = links_apart(np.array([0, 1, 1]), np.full(3, -1))
    assert (model.probability(rows, one_curve) >= 0.5).tolist() == [False, False, True]
    assert (model.probability(rows, apart) >= 0.5).tolist() == [False, False, True]
    assert (model.probability(rows, lifted) >= 0.5).tolist() == [False, True, True]
    model.to_json(tmp_path / "two.json")
    back = EvidenceModel.load(tmp_path / "two.json")
    assert back.second is not None
    np.testing.assert_array_equal(back.probability(rows, lifted), model.probability(rows, lifted))
    with pytest.raises(ValueError, match="second pass reads 1 columns"):
        EvidenceModel(_stump(0, 1, 0.5), 0.5, "m", {}, ("probability",), _stump(0, 1, 0.5))


def test_a_second_pass_of_an_earlier_release_reads_the_first_relayed_columns(tmp_path) -> None:
    # Trained before the neighbours were relayed: its file names no relayed columns.
    curve = FIRST_RELAYED.index("light_curve_flash_probability")
    model = EvidenceModel(
        _stump(0, 1, 0.5),
        0.5,
        DEFAULT_MODEL_NAME,
        {},
        features=("probability",),
        second=_stump(1 + curve, 1 + len(FIRST_RELAYED), 0.5),
        relayed=FIRST_RELAYED,
    )
    model.to_json(tmp_path / "earlier.json")
    data = json.loads((tmp_path / "earlier.json").read_text())
    del data["relayed"]
    (tmp_path / "earlier.json").write_text(json.dumps(data))
    back = EvidenceModel.load(tmp_path / "earlier.json")
    assert back.relayed == FIRST_RELAYED
    rows = np.full((3, len(FEATURES)), 0.2)
    rows[2, FEATURES.index("probability")] = 0.9
    lifted = links_apart(np.array([0, 1, 1]), np.full(3, -1))
    assert (back.probability(rows, lifted) >= 0.5).tolist() == [False, True, True]


def test_the_rules_decide_without_the_models_classifier() -> None:
    params, tracking = AcceptanceParams(), TrackingParams()
    model, why = evidence_model(params, ClassifierParams(), tracking)
    assert model is not None and why is None
    other = ClassifierParams(model="/models/ffnet_gp360_65_rgb.onnx")
    model, why = evidence_model(params, other, tracking)
    assert model is None and "ffnet_gp360_65_rgb.onnx" in why
    model, why = evidence_model(params, ClassifierParams(enabled=False), tracking)
    assert model is None and "no patch classifier" in why
    no_model = AcceptanceParams(evidence_model=None)
    assert evidence_model(no_model, ClassifierParams(), tracking) == (None, None)
    off = AcceptanceParams(enabled=False)
    assert evidence_model(off, ClassifierParams(), tracking) == (None, None)


def test_a_model_of_another_tracking_decides_with_a_warning() -> None:
    shipped = EvidenceModel.load(DEFAULT_EVIDENCE_MODEL)
    assert shipped.tracking == TrackingParams().model_dump(mode="json")
    model, why = evidence_model(AcceptanceParams(), ClassifierParams(), TrackingParams())
    assert model is not None and model.card == shipped.card and why is None
    other = TrackingParams(matched_sigma_px=2.0, deblend=False)
    model, why = evidence_model(AcceptanceParams(), ClassifierParams(), other)
    assert model is not None
    assert "tracked with deblend=True, matched_sigma_px=1.0," in why
    assert "this run tracked with deblend=False, matched_sigma_px=2.0:" in why


def test_a_card_of_an_earlier_release_names_only_its_matched_filter(tmp_path) -> None:
    data = json.loads(DEFAULT_EVIDENCE_MODEL.read_text(encoding="utf-8"))
    del data["tracking"]
    data["matched_sigma_px"] = 1.0
    path = tmp_path / "earlier.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    params = AcceptanceParams(evidence_model=str(path))
    # Deblending is not on its card: only the matched filter can be checked.
    _, why = evidence_model(params, ClassifierParams(), TrackingParams(deblend=False))
    assert why is None
    _, why = evidence_model(params, ClassifierParams(), TrackingParams(matched_sigma_px=0.75))
    assert "matched_sigma_px=1.0" in why and "matched_sigma_px=0.75" in why


def _camera(frames, points, snr, probability, camera):
    local = points if camera == 1 else POSE.world_to_camera2(points, SEPARATION)
    x, y = bearing_to_pixel(local, WIDTH)
    det = Detections.from_columns(
        frames,
        x,
        y,
        snr=snr,
        flash_probability=probability,
        peak=np.asarray(snr) * 2.0,
        recurrence=np.zeros(len(x)),
    )
    chain = spot_chains(det.frame, det.x, det.y, WIDTH, 1.0)
    verdict = np.where(
        (np.asarray(snr) >= 8) & (np.asarray(probability) >= 0.5),
        Verdict.CONFIDENT,
        Verdict.DOUBTFUL,
    ).astype(np.int8)
    return det, Evidence(verdict, steady_frames(det.frame, chain), chain)


def test_the_shipped_model_accepts_a_faint_flash_both_cameras_see_and_not_lone_grain() -> None:
    """A 6–7 σ firefly lit 4 frames in both cameras (doubtful by the rules' 8 σ) is a
    flash; faint spots lit one frame in one camera only, which the classifier doubts,
    are not."""
    track = np.array([[4.0 + 0.02 * i, 3.0, 1.0] for i in range(4)])
    grain = np.array([[-2.0, -5.0, 0.5], [1.0, 6.0, -0.5], [-5.0, 1.0, 1.5]])
    det1, ev1 = _camera(
        [10, 11, 12, 13, 40, 80, 120],
        np.vstack([track, grain]),
        [6.0, 7.0, 6.5, 6.0, 5.0, 5.5, 4.8],
        [0.7, 0.8, 0.8, 0.7, 0.3, 0.2, 0.3],
        1,
    )
    det2, ev2 = _camera([10, 11, 12, 13], track, [6.5, 7.0, 7.5, 6.0], [0.7, 0.8, 0.9, 0.7], 2)
    model = EvidenceModel.load(DEFAULT_EVIDENCE_MODEL)
    gates = TriangulationParams(max_gap_deg=1.0)
    matches = stereo_matches((det1, det2), 0, POSE, WIDTH, SEPARATION, gates)
    weighed = weigh(model, (det1, det2), (ev1, ev2), matches, WIDTH, FPS, FlickerParams())
    assert weighed.accepted1.tolist() == [True] * 4 + [False] * 3, weighed.probability1
    assert weighed.accepted2.tolist() == [True] * 4, weighed.probability2
    assert weighed.matched1.tolist() == [True] * 4 + [False] * 3
    # A threshold above every probability accepts nothing.
    none = weigh(model, (det1, det2), (ev1, ev2), matches, WIDTH, FPS, FlickerParams(), 1.0)
    assert not none.accepted1.any() and not none.accepted2.any()


def test_counts_say_what_was_done_with_each_verdict() -> None:
    v = Verdict
    verdict = np.array(
        [
            v.CONFIDENT,
            v.CONFIDENT,
            v.DOUBTFUL,
            v.DOUBTFUL,
            v.DOUBTFUL,
            v.FLICKER,
            v.STEADY,
            v.CLASSIFIER,
            v.RECURRENT,
            v.RECURRENT,
        ],
        np.int8,
    )
    accepted = np.array([1, 0, 1, 1, 0, 0, 0, 0, 1, 0], bool)
    matched = np.array([1, 1, 1, 0, 1, 0, 0, 0, 0, 0], bool)
    counts = acceptance_counts(verdict, accepted, matched)
    assert counts == {
        "candidates": 10,
        "accepted": 4,
        "accepted_confident": 1,
        "accepted_stereo": 1,
        "accepted_single_camera": 2,
        "accepted_over_rules": 1,
        "rejected_confident": 1,
        "rejected_unconfirmed": 1,
        "rejected_flicker": 1,
        "rejected_light_curve": 1,
        "rejected_classifier": 1,
        "rejected_recurrent": 1,
    }
    rejected = sum(n for k, n in counts.items() if k.startswith("rejected_"))
    assert counts["candidates"] == counts["accepted"] + rejected
