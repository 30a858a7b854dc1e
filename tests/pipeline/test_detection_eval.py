"""`pipeline.detection_eval` and ``firefly3d eval-detection``: binning, matching and pooling
on hand-made truth with known answers, the JSON document, and one small run end to end."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.detection_eval import (
    SCHEMA_VERSION,
    binned,
    cut_figures,
    detection_figures,
    finite,
    flash_event_figures,
    pair_rows,
    point_figures,
    pool,
    stereo_figures,
)
from pipeline.detection_eval_cli import (
    LOSSLESS,
    is_lossless,
    night_name,
    register,
    simulation_configs,
)
from pipeline.detections import Detections
from pipeline.evaluate import match_detections
from pipeline.evidence_model import DEFAULT_EVIDENCE_MODEL, EvidenceModel
from pipeline.geometry import Pose
from pipeline.simulate import ArtifactTruth, FlashTruth, GroundTruth

W, H = 640, 320


def hand_truth() -> GroundTruth:
    """Five flash-frames (row 4 hidden from camera 1) and one open sky glint."""
    position = np.array(
        [[3.0, 0, 0], [0, 6.0, 0], [9.0, 0, 0], [25.0, 0, 0], [0, 4.0, 0]], dtype=float
    )
    snr1 = np.array([2.0, 4.0, 7.0, 30.0, 12.0])
    flashes = FlashTruth(
        flash_id=np.arange(5),
        firefly_id=np.arange(5),
        frame1=np.array([0, 0, 1, 2, 3]),
        frame2=np.array([0, 0, 1, 2, 3]),
        x=position[:, 0],
        y=position[:, 1],
        z=position[:, 2],
        u1=np.array([100.0, 300.0, 100.5, 639.5, 50.0]),
        v1=np.array([160.0, 150.0, 160.0, 160.0, 100.0]),
        visible1=np.array([True, True, True, True, False]),
        u2=np.array([101.0, 301.0, 101.5, 0.5, 51.0]),
        v2=np.array([160.0, 150.0, 160.0, 160.0, 100.0]),
        visible2=np.ones(5, dtype=bool),
        intensity=np.ones(5),
        peak1=np.full(5, 50.0),
        peak2=np.full(5, 50.0),
        range1=np.linalg.norm(position, axis=1),
        range2=np.linalg.norm(position, axis=1),
        snr1=snr1,
        snr2=snr1 + 1.0,
        # Grain: a matched filter sees less; row 1 (missed) stays above 5 σ.
        snr_mf1=np.array([1.0, 6.0, 4.0, 20.0, 8.0]),
        snr_mf2=snr1 / 2,
        psf1=np.array([0.7, 1.0, 1.5, 1.9, 1.0]),
        psf2=np.full(5, 1.0),
    )
    artifacts = ArtifactTruth(
        camera=[1], frame=[3], u=[52.0], v=[100.0], radius=[3.0], kind=["glint"]
    )
    return GroundTruth(
        delay_frames=0,
        pose=Pose(rotation=np.eye(3), translation=np.array([1.0, 0.0, 0.0])),
        separation_m=1.5,
        camera_height_m=1.2,
        fps=30.0,
        width=W,
        height=H,
        n_frames1=4,
        n_frames2=4,
        scenario="hand",
        seed=0,
        flashes=flashes,
        artifacts=artifacts,
    )


def hand_detections() -> Detections:
    return Detections.from_columns(
        frame=[0, 0, 1, 2, 3, 1],
        x=[101.5, 300.0, 100.5, 0.5, 50.0, 400.0],
        y=[160.0, 153.0, 160.0, 160.0, 100.0, 200.0],
    )


def by_label(bins: list[dict]) -> dict[str, dict]:
    return {b["label"]: b for b in bins}


def test_binned_counts_hits_per_bin_and_unknowns() -> None:
    values = np.array([0.0, 2.9, 3.0, 4.99, 5.0, 19.0, 20.0, 1e9, np.inf, np.nan])
    hits = np.array([1, 0, 1, 1, 0, 1, 1, 0, 1, 1], dtype=bool)
    bins = by_label(binned(values, [("found", hits)], (0, 3, 5, 10, 20, math.inf)))
    assert list(bins) == ["0-3", "3-5", "5-10", "10-20", ">=20", "unknown"]
    assert [bins[k]["n"] for k in bins] == [2, 2, 1, 1, 3, 1]
    assert [bins[k]["found"] for k in bins] == [1, 2, 0, 1, 2, 1]
    assert bins["3-5"]["found_rate"] == 1.0
    assert bins[">=20"]["hi"] is None and bins[">=20"]["lo"] == 20
    assert bins["10-20"]["found_rate"] == 1.0
    # An empty bin has no rate (JSON null), and no "unknown" bin without NaN values.
    empty = by_label(binned(np.array([1.0]), [("found", np.array([True]))], (0, 3, 5)))
    assert list(empty) == ["0-3", "3-5"] and empty["3-5"]["found_rate"] is None


def test_detection_figures_on_hand_made_truth() -> None:
    truth = hand_truth()
    det = hand_detections()
    figures = detection_figures(det, match_detections(det, truth, 1), truth, 1, n_frames=4)
    assert figures["n_truth"] == 4  # the hidden row does not count
    assert figures["n_found"] == 3 and figures["recall"] == 0.75  # row 1 missed (3 px off)
    assert figures["n_truth_snr_ge5"] == 2 and figures["recall_snr_ge5"] == 1.0
    assert figures["n_truth_mf_snr_ge5"] == 2 and figures["recall_mf_snr_ge5"] == 0.5
    assert figures["n_flashes_snr_ge5"] == 2 and figures["flash_recall_snr_ge5"] == 1.0
    mf = by_label(figures["by_mf_snr"])
    assert [(mf[k]["n"], mf[k]["found"]) for k in mf] == [(1, 1), (1, 1), (1, 0), (0, 0), (1, 1)]
    assert figures["n_detections"] == 6 and figures["n_true"] == 3
    assert figures["precision"] == 0.5
    assert figures["per_frame"] == 1.5 and figures["false_per_frame"] == 0.75
    # The seam: a detection at u = 0.5 matches the flash at u = 639.5.
    assert figures["false_by_kind"] == {"glint": 1, "near_flash": 1, "other": 1}
    snr = by_label(figures["by_snr"])
    assert [(snr[k]["n"], snr[k]["found"]) for k in snr] == [(1, 1), (1, 0), (1, 1), (0, 0), (1, 1)]
    assert snr["10-20"]["found_rate"] is None
    rng = by_label(figures["by_range_m"])
    assert [(rng[k]["n"], rng[k]["found"]) for k in rng] == [(1, 1), (1, 0), (1, 1), (1, 1)]
    # Spot size of the two flash-frames >= 5 sigma (rows 2 and 3, both found).
    psf = by_label(figures["by_psf_px_snr_ge5"])
    assert [(psf[k]["n"], psf[k]["found"]) for k in psf] == [(0, 0), (0, 0), (1, 1), (1, 1)]
    # Position errors of the three found: 0 px, 1 px across the seam, 1.5 px.
    assert figures["median_error_px"] == pytest.approx(1.0, abs=1e-4)  # chord, not arc
    errors = by_label(figures["by_error_px"])
    assert sum(b["n"] for b in errors.values()) == 3 and errors["0-0.1"]["n"] == 1
    assert errors["1-2"]["n"] >= 1 and errors["0.1-0.2"]["n"] == 0


def test_flash_event_figures_count_whole_flashes_and_misses_beside_found_frames() -> None:
    flash_id = np.array([7, 7, 7, 7, 7, 9, 9, 6, 4, 4, 5, 3, 3])
    frame = np.array([10, 11, 12, 13, 14, 15, 16, 16, 3, 4, 20, -1, 0])
    snr = np.array([3.0, 8, 12, 9, 6, 6, 4, 20, 2, 4, 30, 10, 7])
    found = np.array([0, 1, 1, 0, 0, 0, 0, 1, 0, 0, 0, 1, 0], dtype=bool)
    figures = flash_event_figures(flash_id, frame, snr, found)
    # Flashes of peak >= 5: 7, 9, 6, 5, 3 (4 peaks at 4); found: 7, 6, 3.
    assert figures["n_flashes_snr_ge5"] == 5 and figures["n_flashes_found_snr_ge5"] == 3
    assert figures["flash_recall_snr_ge5"] == 0.6
    # Missed >= 5: flash 7 at 13 and 14 (1 and 2 frames after 12), flash 3 at 0 (beside
    # -1), flash 9 at 15 (beside flash 6's found frame 16, another flash) and flash 5.
    assert figures["n_missed_snr_ge5_beside_found"] == 3
    nothing = flash_event_figures(*(np.zeros(0, t) for t in (np.int64, np.int64, float, bool)))
    assert nothing["n_flashes_snr_ge5"] == 0 and nothing["flash_recall_snr_ge5"] is None


def test_stereo_figures_count_flashes_detected_by_both_cameras() -> None:
    truth = hand_truth()
    cam2 = Detections.from_columns(
        frame=[0, 1, 2, 3], x=[101.0, 101.5, 0.5, 51.0], y=[160.0, 160.0, 160.0, 100.0]
    )
    match1 = match_detections(hand_detections(), truth, 1)
    figures = stereo_figures(match1, match_detections(cam2, truth, 2), truth)
    # Rows 0-3 are seen by both cameras; row 1 is found by neither, row 4 by camera 2 only.
    assert figures["n_truth"] == 4 and figures["n_found"] == 3 and figures["recall"] == 0.75
    assert figures["n_truth_snr_ge5"] == 2 and figures["recall_snr_ge5"] == 1.0
    rng = by_label(figures["by_range_m"])
    assert [rng[k]["found"] for k in rng] == [1, 0, 1, 1]
    # Nothing detected by camera 2: nothing for triangulation.
    none = match_detections(cam2.select(np.zeros(0, int)), truth, 2)
    assert stereo_figures(match1, none, truth)["n_found"] == 0


def test_finite_makes_strict_json() -> None:
    assert finite({"a": [1.0, math.nan, {"b": math.inf}], "c": "x", "d": 2}) == {
        "a": [1.0, None, {"b": None}],
        "c": "x",
        "d": 2,
    }


def test_point_figures_on_hand_made_truth() -> None:
    truth = hand_truth()
    xyz = np.array([[3.1, 0, 0], [0, 6.05, 0], [20.0, 0, 0]])
    frame = np.array([0, 0, 2])
    figures = point_figures(xyz, frame, truth)
    assert figures["n_truth"] == 4  # seen by both cameras
    assert figures["n_found"] == 2 and figures["recall"] == 0.5  # within 5 % of range
    assert figures["n_found_within_2pct"] == 1 and figures["recall_within_2pct"] == 0.25
    assert figures["n_points"] == 3 and figures["n_true"] == 2
    assert figures["precision"] == pytest.approx(2 / 3)
    rng = by_label(figures["by_range_m"])
    assert rng["0-5"]["found"] == 1 and rng["0-5"]["found_within_2pct"] == 0
    assert rng["5-8"]["found_within_2pct"] == 1
    assert rng["8-20"]["found"] == 0 and rng[">=20"]["found"] == 0
    snr = by_label(figures["by_snr"])  # min of both cameras' SNR: camera 1's here
    assert snr["0-3"]["n"] == 1 and snr[">=20"]["n"] == 1
    # Whole flashes of smaller peak >= 5: rows 2 (no point) and 3 (20 % off).
    assert figures["n_flashes_snr_ge5"] == 2 and figures["flash_recall_snr_ge5"] == 0.0
    assert "coverage" not in figures  # no standard deviations given
    assert "coverage" not in point_figures(xyz, frame, truth, np.array([0.1, np.nan, 3.0]))


def test_range_standard_deviations_are_scored_by_coverage_and_sure_precision() -> None:
    truth = hand_truth()
    xyz = np.array([[3.1, 0, 0], [0, 6.05, 0], [20.0, 0, 0]])  # 0.1, 0.05 and 5 m off
    figures = point_figures(xyz, np.array([0, 0, 2]), truth, np.array([0.1, 0.01, 3.0]))
    # Within 2 σ: 0.1 <= 0.2 and 5 <= 6, not 0.05 > 0.02.
    assert figures["n_matched"] == 3 and figures["n_covered"] == 2
    assert figures["coverage"] == pytest.approx(2 / 3)
    # Sure within 2 % of range: only the second point (0.01 / 6.05), and it is true.
    assert figures["n_sure"] == 1 and figures["n_sure_true"] == 1
    assert figures["precision_sure"] == 1.0
    wider = point_figures(xyz, np.array([0, 0, 2]), truth, np.array([0.1, 0.03, 3.0]))
    assert wider["n_covered"] == 3 and wider["n_sure"] == 1
    pooled = pool([{"cameras": _no_cameras(), "points_3d": f} for f in (figures, wider)])
    assert pooled["points_3d"]["coverage"] == pytest.approx(5 / 6)
    assert pooled["points_3d"]["precision_sure"] == 1.0


def test_stereo_pairing_is_scored_apart_from_range_error() -> None:
    truth = hand_truth()
    cam2 = Detections.from_columns(
        frame=[0, 0, 2, 3], x=[101.0, 301.0, 0.5, 51.0], y=[160.0, 150.0, 160.0, 100.0]
    )
    # Points from: row 0 in both (right pair), row 1 only in camera 2 (camera 1's
    # detection is 3 px off: false), rows 0 and 1 crossed (mispaired), row 3 in both
    # across the seam (right pair), camera 1's false detection with row 4 of camera 2.
    index1 = np.array([0, 1, 0, 3, 5])
    index2 = np.array([0, 1, 1, 2, 3])
    match1 = match_detections(hand_detections(), truth, 1)
    rows = pair_rows(index1, index2, match1, match_detections(cam2, truth, 2))
    assert rows.tolist() == [0, -1, -1, 3, -1]
    # The right pair of row 0 triangulated 20 % off in range still counts as paired.
    xyz = np.array([[3.6, 0, 0], [0, 6.0, 0], [3.0, 0, 0], [25.0, 0, 0], [0, 4.0, 0]])
    frame = np.array([0, 0, 0, 2, 3])
    figures = point_figures(xyz, frame, truth, pair_row=rows)
    assert figures["n_pair_points"] == 5 and figures["n_pair_true"] == 2
    assert figures["pair_precision"] == pytest.approx(2 / 5)
    assert figures["n_truth"] == 4 and figures["n_found_paired"] == 2
    assert figures["pair_recall"] == 0.5
    # Within 5 %: rows 1 (a false pair that lands on it), 0 (the mispaired point) and 3.
    assert figures["n_found"] == 3
    snr = by_label(figures["by_snr"])  # rows 0 (2 σ) and 3 (30 σ) are paired
    assert snr["0-3"]["found_paired"] == 1 and snr[">=20"]["found_paired"] == 1
    assert snr["3-5"]["found_paired"] == 0
    assert "pair_recall" not in point_figures(xyz, frame, truth)
    pooled = pool([{"cameras": _no_cameras(), "points_3d": figures}] * 2)
    assert pooled["points_3d"]["pair_precision"] == pytest.approx(2 / 5)
    assert pooled["points_3d"]["pair_recall"] == 0.5


def test_cut_figures_score_the_candidates_at_or_above_each_cut() -> None:
    truth = hand_truth()
    # Rows 0, 2, 3 are true (flashes of SNR 2, 7 and 30); 1, 4 and 5 are not.
    probability = np.array([0.9, 0.2, 0.7, 0.95, 0.6, 0.8])
    every, likely, none = cut_figures(hand_detections(), probability, truth, 1, [0.0, 0.75, 1.0])
    assert every["cut"] == 0.0 and (every["n_detections"], every["n_true"]) == (6, 3)
    assert every["n_truth_snr_ge5"] == 2 and every["recall_snr_ge5"] == 1.0
    assert every["f1_snr_ge5"] == pytest.approx(2 / 3)
    # At 0.75 rows 0, 3 and 5: the 7 σ flash (row 2, 0.7) is lost, the false row 5 kept.
    assert (likely["n_detections"], likely["n_true"], likely["n_found_snr_ge5"]) == (3, 2, 1)
    assert likely["precision"] == pytest.approx(2 / 3) and likely["recall_snr_ge5"] == 0.5
    assert likely["f1_snr_ge5"] == pytest.approx(4 / 7)
    assert none["n_detections"] == 0 and none["precision"] is None
    assert none["recall_snr_ge5"] == 0.0 and none["f1_snr_ge5"] is None
    # Pooled cut by cut; a run scored by the rules (None) adds nothing.
    runs = [
        {"seed": seed, "cameras": _no_cameras(), "points_3d": None, "cuts": cuts}
        for seed, cuts in (
            (1, {"cam1": [every, likely], "cam2": None}),
            (2, {"cam1": [every, likely], "cam2": None}),
            (3, None),
        )
    ]
    pooled = pool(runs)["cuts"]
    assert pooled["cam2"] is None
    assert [e["cut"] for e in pooled["cam1"]] == [0.0, 0.75]
    assert (pooled["cam1"][1]["n_detections"], pooled["cam1"][1]["n_true"]) == (6, 4)
    assert pooled["cam1"][1]["precision"] == pytest.approx(2 / 3)
    assert pooled["cam1"][1]["f1_snr_ge5"] == pytest.approx(4 / 7)


def _no_cameras() -> dict[str, dict[str, None]]:
    return {cam: {"accepted": None, "candidates": None} for cam in ("cam1", "cam2")}


def test_pool_adds_counts_and_recomputes_ratios() -> None:
    truth = hand_truth()
    det = hand_detections()
    match = match_detections(det, truth, 1)
    run = {
        "seed": 1,
        "cameras": {
            cam: {
                "accepted": detection_figures(det, match, truth, 1, 4),
                "candidates": detection_figures(det, match, truth, 1, 4),
            }
            for cam in ("cam1", "cam2")
        },
        "points_3d": point_figures(np.array([[3.1, 0, 0]]), np.array([0]), truth),
    }
    other = json.loads(json.dumps(run)) | {"seed": 2}
    first = det.select(np.arange(1))
    other["cameras"]["cam1"]["accepted"] = detection_figures(
        first, match_detections(first, truth, 1), truth, 1, 4
    )
    pooled = pool([run, other])
    acc = pooled["cameras"]["cam1"]["accepted"]
    assert pooled["n_runs"] == 2 and pooled["seeds"] == [1, 2]
    assert acc["n_truth"] == 8 and acc["n_found"] == 4 and acc["recall"] == 0.5
    assert acc["n_detections"] == 7 and acc["n_true"] == 4
    assert acc["precision"] == pytest.approx(4 / 7)
    assert acc["per_frame"] == pytest.approx(7 / 8)
    assert acc["false_by_kind"] == {"glint": 1, "near_flash": 1, "other": 1}
    assert by_label(acc["by_snr"])["0-3"] == {
        "label": "0-3",
        "lo": 0.0,
        "hi": 3.0,
        "n": 2,
        "found": 2,
        "found_rate": 1.0,
    }
    points = pooled["points_3d"]
    assert points["n_truth"] == 8 and points["n_found"] == 2 and points["recall"] == 0.25


def test_eval_detection_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Simulate a short clean night, run the pipeline, score it; then score the same
    folders again from --recording/--results."""
    out = tmp_path / "scores.json"
    params = tmp_path / "params.json"  # 8 s is shorter than the default delay window
    params.write_text(json.dumps({"sync": {"window_s": 4.0}}))
    args = ["eval-detection", "--scenario", "clean", "--seeds", "3", "--seconds", "8"]
    args += ["--width", "640", "--cache", str(tmp_path / "cache"), "--params", str(params)]
    threshold = EvidenceModel.load(DEFAULT_EVIDENCE_MODEL).threshold
    args += ["--json", str(out), "--quiet", "--cuts", "0.3", str(threshold), "0.99"]
    assert main(args) == 0
    table = capsys.readouterr().out
    assert "clean s3" in table and "SNR>=5" in table
    document = json.loads(out.read_text())
    assert document["schema_version"] == SCHEMA_VERSION
    assert set(document) == {"schema_version", "tolerances", "bins", "params", "runs", "pooled"}
    json.loads(out.read_text(), parse_constant=pytest.fail)  # strict JSON: no NaN
    assert document["bins"]["snr"] == [0.0, 3.0, 5.0, 10.0, 20.0, None]
    assert document["bins"]["range_m"] == [0.0, 5.0, 8.0, 20.0, None]
    assert document["tolerances"]["detection_px"] == 2.0
    assert document["params"]["sync"]["window_s"] == 4.0
    (run,) = document["runs"]
    assert (run["scenario"], run["seed"], run["width"], run["error"]) == ("clean", 3, 640, None)
    for cam in ("cam1", "cam2"):
        accepted, candidates = run["cameras"][cam]["accepted"], run["cameras"][cam]["candidates"]
        # The clean night is easy: bright flashes, nothing else.
        assert accepted["n_truth"] > 100
        assert accepted["recall"] > 0.9 and accepted["precision"] > 0.95
        assert candidates["recall"] >= accepted["recall"]
        assert candidates["n_detections"] >= accepted["n_detections"]
        assert accepted["per_frame"] == pytest.approx(accepted["n_detections"] / 240)
        assert sum(b["n"] for b in accepted["by_snr"]) == accepted["n_truth"]
        assert sum(b["n"] for b in accepted["by_range_m"]) == accepted["n_truth"]
    points = run["points_3d"]
    assert points["n_truth"] > 100 and points["n_points"] > 0
    assert 0.0 <= points["recall_within_2pct"] <= points["recall"] <= 1.0
    assert 0.5 < points["coverage"] <= 1.0 and points["n_sure"] > 0
    stereo = run["stereo"]["accepted"]
    assert stereo["n_truth"] == points["n_truth"] and stereo["recall"] > 0.9
    assert points["recall"] <= stereo["recall"] + 0.02  # triangulation needs both cameras
    # Pairing, whatever the range error: every point is scored, nearly all pairs are
    # right, and a paired flash-frame was necessarily detected by both cameras.
    assert points["n_pair_points"] == points["n_points"] and points["pair_precision"] > 0.95
    assert points["recall"] - 0.02 <= points["pair_recall"] <= stereo["recall"]
    assert "pair rec/prec" in table
    assert run["accuracy"]["delay_error_frames"] == 0
    # At the model's own cut the candidates scored are exactly the accepted detections;
    # a higher cut keeps fewer of them.
    assert "evidence-model cut" in table
    for cam in ("cam1", "cam2"):
        low, own, high = run["cuts"][cam]
        accepted = run["cameras"][cam]["accepted"]
        for key in ("n_detections", "n_true", "n_found_snr_ge5", "n_truth_snr_ge5"):
            assert own[key] == accepted[key]
        assert low["n_detections"] >= own["n_detections"] >= high["n_detections"]
    assert document["pooled"]["clean"]["n_runs"] == 1

    again = tmp_path / "again.json"
    rescore = ["eval-detection", "--recording", run["recording"], "--results", run["results"]]
    assert main([*rescore, "--json", str(again), "--quiet"]) == 0
    assert json.loads(again.read_text())["runs"][0]["cameras"] == run["cameras"]


def test_eval_detection_needs_something_to_score(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval-detection"]) == 2
    assert "--scenario" in capsys.readouterr().err


def test_a_lossless_twin_differs_from_its_night_in_the_encoding_only() -> None:
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    args = parser.parse_args(
        ["eval-detection", "--scenario", "hard-wind", "--seeds", "4", "5", "--lossless-twin"]
    )
    configs = simulation_configs(args)
    assert [(c.seed, is_lossless(c.model_dump())) for c in configs] == [
        (4, False),
        (4, True),
        (5, False),
        (5, True),
    ]
    night, twin = configs[0].model_dump(), configs[1].model_dump()
    assert night["bits_per_pixel"] == 0.16  # the scenario's camera-like bitrate
    assert {k for k in night if night[k] != twin[k]} <= set(LOSSLESS)
    assert night_name({"scenario": "hard-wind", "seed": 4, "lossless": True}) == (
        "hard-wind s4 lossless"
    )
