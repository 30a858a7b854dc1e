"""The evidence on each candidate as numbers (pipeline.evidence_features)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from pipeline.acceptance import Evidence, Verdict, assess, spot_chains, steady_frames
from pipeline.detections import Detections
from pipeline.evidence_features import (
    BRIGHTER_NEIGHBOUR_PX,
    CROWD_BLOCK_S,
    FEATURES,
    NEIGHBOUR_MIN_GAP_S,
    NEIGHBOUR_RADIUS_DEG,
    NEIGHBOUR_WINDOW_S,
    RELAYED,
    CandidateLinks,
    as_strong_per_frame,
    brighter_neighbours,
    candidate_features,
    candidate_links,
    neighbour_probabilities,
    relayed_probabilities,
    stereo_matches,
)
from pipeline.geometry import Pose, bearing_to_pixel
from pipeline.params import AcceptanceParams, FlickerParams, TriangulationParams
from tests.pipeline.links_factory import links_apart

WIDTH, SEPARATION = 640, 1.5
POSE = Pose(np.eye(3), [1.0, 0.0, 0.0])
GATES = TriangulationParams(max_gap_deg=1.0)


def _seen(points: NDArray[np.float64], camera: int) -> tuple[NDArray, NDArray]:
    local = points if camera == 1 else POSE.world_to_camera2(points, SEPARATION)
    return bearing_to_pixel(local, WIDTH)


def _camera(frames, points, snr, probability, camera: int) -> tuple[Detections, Evidence]:
    x, y = _seen(np.asarray(points, float), camera)
    det = Detections.from_columns(
        frames, x, y, snr=snr, flash_probability=probability, peak=np.full(len(x), 40.0)
    )
    chain = spot_chains(det.frame, det.x, det.y, WIDTH, 1.0)
    verdict = np.where(np.asarray(snr) >= 8, Verdict.CONFIDENT, Verdict.DOUBTFUL).astype(np.int8)
    return det, Evidence(verdict, steady_frames(det.frame, chain), chain)


def _scene(frames: int = 4):
    """A firefly lit `frames` frames seen by both cameras (faint), and a noise spot in
    camera 1."""
    track = [[4.0 + 0.08 * i / frames, 3.0, 1.0] for i in range(frames)]
    snr1 = np.resize([6.0, 7.0, 6.5, 5.5], frames)
    snr2 = np.resize([5.5, 6.5, 9.0, 5.0], frames)
    probability2 = np.resize([0.5, 0.6, 0.9, 0.5], frames)
    noise = [[-2.0, -5.0, 0.5]]
    det1, ev1 = _camera(
        [*range(frames), 50], [*track, *noise], [*snr1, 4.5], [0.6] * frames + [0.2], 1
    )
    det2, ev2 = _camera(np.arange(frames), track, snr2, probability2, 2)
    return (det1, det2), (ev1, ev2)


def _features(candidates, evidence, fps: float):
    matches = stereo_matches(candidates, 0, POSE, WIDTH, SEPARATION, GATES)
    return candidate_features(candidates, evidence, matches, WIDTH, fps, FlickerParams())


def _col(rows: NDArray, name: str) -> NDArray:
    return rows[:, FEATURES.index(name)]


def test_a_flash_seen_by_both_cameras_carries_the_other_cameras_evidence() -> None:
    candidates, evidence = _scene()
    rows1, rows2 = _features(candidates, evidence, fps=30.0)
    assert rows1.shape == (5, len(FEATURES)) and rows2.shape == (4, len(FEATURES))
    assert _col(rows1, "stereo_matched").tolist() == [1, 1, 1, 1, 0]
    np.testing.assert_allclose(np.exp(_col(rows1, "other_snr_log")[:4]), [5.5, 6.5, 9.0, 5.0])
    np.testing.assert_allclose(np.exp(_col(rows2, "other_snr_log")), [6.0, 7.0, 6.5, 5.5])
    np.testing.assert_allclose(_col(rows1, "other_probability")[:4], [0.5, 0.6, 0.9, 0.5])
    assert _col(rows1, "other_verdict_confident")[:4].tolist() == [0, 0, 1, 0]
    # The two light curves are matched in 4 frames; the best weaker side is 6.5 σ.
    np.testing.assert_allclose(_col(rows1, "pair_s")[:4], 4 / 30)
    np.testing.assert_allclose(np.exp(_col(rows2, "pair_peak_snr_log")), 6.5)
    assert np.all(_col(rows1, "gap_deg")[:4] < 0.01)  # noise-free positions
    # Unmatched: every stereo column but the flag is missing.
    stereo = [FEATURES.index(n) for n in FEATURES[FEATURES.index("other_snr_log") :]]
    assert np.all(np.isnan(rows1[4, stereo]))


def test_own_evidence_columns_describe_the_light_curve() -> None:
    candidates, evidence = _scene()
    rows1, _ = _features(candidates, evidence, fps=30.0)
    np.testing.assert_allclose(np.exp(_col(rows1, "snr_log")), [6.0, 7.0, 6.5, 5.5, 4.5])
    np.testing.assert_allclose(_col(rows1, "lit_s"), [4 / 30] * 4 + [1 / 30])
    np.testing.assert_allclose(np.exp(_col(rows1, "chain_peak_snr_log")), [7.0] * 4 + [4.5])
    np.testing.assert_allclose(_col(rows1, "chain_candidates_s"), [4 / 30] * 4 + [1 / 30])
    verdicts = rows1[:, [FEATURES.index(f"verdict_{v.name.lower()}") for v in Verdict]]
    assert verdicts.sum(axis=1).tolist() == [1] * 5 and np.all(verdicts[:, 1] == 1)
    assert np.all(np.isnan(_col(rows1, "recurrence")))  # not measured here
    assert np.all(_col(rows1, "flicker_duty") > 0)
    # The noise at the spot: peak 40 grey levels over its SNR.
    np.testing.assert_allclose(
        np.exp(_col(rows1, "noise_log")), 40.0 / np.exp(_col(rows1, "snr_log"))
    )
    # Each candidate against its light curve's best (7 σ; the noise spot is its own).
    np.testing.assert_allclose(
        np.exp(_col(rows1, "chain_snr_share_log")), [6 / 7, 1.0, 6.5 / 7, 5.5 / 7, 1.0]
    )
    np.testing.assert_allclose(_col(rows1, "candidate_lit_share"), 1.0)
    assert np.all(np.isnan(_col(rows1, "trough")))  # not measured here
    assert np.all(np.isnan(_col(rows1, "hollow")))


def test_the_dark_spots_the_tracker_measured_are_read() -> None:
    (det1, det2), evidence = _scene()
    troughs = np.array([-0.02, -0.6, 0.0, -0.1, -1.5])
    hollows = np.array([0.0, -0.9, -0.05, 0.1, -0.3])
    det1 = replace(det1, trough=troughs.astype(np.float32), hollow=hollows.astype(np.float32))
    rows1, _ = _features((det1, det2), evidence, fps=30.0)
    np.testing.assert_allclose(_col(rows1, "trough"), troughs, rtol=1e-6)
    np.testing.assert_allclose(_col(rows1, "hollow"), hollows, rtol=1e-6)


def test_faint_peaks_lengthening_the_lit_spell_lower_the_candidates_share() -> None:
    """A spot lit 8 frames of which the candidates hold 4 (faint peaks the rest), as in
    wind, where leaf clutter at a flash's spot lengthens its spell."""
    candidates, evidence = _scene()
    longer = tuple(replace(e, lit_frames=e.lit_frames * 2) for e in evidence)
    rows1, _ = _features(candidates, longer, fps=30.0)
    np.testing.assert_allclose(_col(rows1, "candidate_lit_share"), 0.5)
    np.testing.assert_allclose(_col(rows1, "lit_s"), [8 / 30] * 4 + [2 / 30])


def test_the_flicker_duty_the_merge_stage_measured_is_the_one_read() -> None:
    candidates, evidence = _scene()
    measured = [
        assess(c, WIDTH, 30.0, 0.5, AcceptanceParams(), FlickerParams()) for c in candidates
    ]
    assert all(m.flicker_duty is not None for m in measured)
    stored = tuple(
        replace(e, flicker_duty=m.flicker_duty) for e, m in zip(evidence, measured, strict=True)
    )
    recomputed = _features(candidates, evidence, fps=30.0)
    for read, again in zip(_features(candidates, stored, fps=30.0), recomputed, strict=True):
        np.testing.assert_array_equal(read, again)
    halved = (replace(stored[0], flicker_duty=measured[0].flicker_duty / 2), stored[1])
    assert np.array_equal(
        _col(_features(candidates, halved, fps=30.0)[0], "flicker_duty"),
        _col(recomputed[0], "flicker_duty") / 2,
    )


def test_durations_read_the_same_at_another_frame_rate() -> None:
    """A flash lit 4 frames at 30 fps lights 8 at 60: the same seconds."""
    at30 = _features(*_scene(4), fps=30.0)[0]
    at60 = _features(*_scene(8), fps=60.0)[0]
    for name in ("lit_s", "candidate_lit_s", "chain_candidates_s", "pair_s"):
        np.testing.assert_allclose(_col(at60, name)[0], _col(at30, name)[0])
    np.testing.assert_allclose(_col(at60, "pair_s")[:8], 8 / 60)


def test_a_spot_lit_again_and_again_counts_its_revisits_a_passing_firefly_does_not() -> None:
    """A hole in the leaves lights one pixel for 3 frames every second; a firefly flashes
    as often but has moved several degrees by its next flash."""
    starts = np.arange(0, 150, 30)
    frames = np.concatenate([s + np.arange(3) for s in starts])
    hole = np.column_stack([np.full(len(frames), 200.0), np.full(len(frames), 140.0)])
    firefly = np.column_stack([400.0 + 2.0 * frames / 30 * 3, np.full(len(frames), 100.0)])
    x = np.r_[hole[:, 0], firefly[:, 0]]
    y = np.r_[hole[:, 1], firefly[:, 1]]
    det = Detections.from_columns(
        np.r_[frames, frames],
        x,
        y,
        snr=np.full(2 * len(frames), 9.0),
        flash_probability=np.full(2 * len(frames), 0.9),
        peak=np.full(2 * len(frames), 30.0),
    )
    chain = spot_chains(det.frame, det.x, det.y, WIDTH, 1.0)
    ev = Evidence(np.zeros(len(det), np.int8), steady_frames(det.frame, chain), chain)
    empty = Detections.from_columns([], [], [])
    empty_ev = Evidence(np.zeros(0, np.int8), np.zeros(0, np.int64), np.zeros(0, np.intp))
    matches = stereo_matches((det, empty), 0, POSE, WIDTH, SEPARATION, GATES)
    rows, _ = candidate_features(
        (det, empty), (ev, empty_ev), matches, WIDTH, 30.0, FlickerParams()
    )
    revisits = _col(rows, "spot_revisits")
    assert revisits[: len(frames)].tolist() == [len(starts) - 1] * len(frames)
    assert revisits[len(frames) :].tolist() == [0] * len(frames)


def test_a_crowded_frame_counts_more_candidates_as_strong() -> None:
    """Block 0 (frames 0-299 at 30 fps) holds a quiet minute's worth: 3 candidates over
    its 300 frames; block 1 is crowded: 60 candidates at 5 sigma over the frames up to
    its last one, and one at 20 sigma."""
    fps = 30.0
    length = round(CROWD_BLOCK_S * fps)
    frame = np.r_[[0, 150, 299], length + np.arange(60) // 2, length + 59]
    snr = np.r_[[5.0, 20.0, 5.0], np.full(60, 5.0), 20.0]
    rate = as_strong_per_frame(frame, snr, fps)
    # Quiet block: the two 5 sigma ones count each other and the 20 sigma one.
    np.testing.assert_allclose(rate[:3], [3 / 300, 1 / 300, 3 / 300])
    # Crowded block: 60 frames up to its last candidate; ties count each other.
    np.testing.assert_allclose(rate[3:63], 61 / 60)
    np.testing.assert_allclose(rate[63], 1 / 60)
    assert as_strong_per_frame(np.zeros(0, int), np.zeros(0), fps).shape == (0,)


def test_the_crowd_of_a_candidate_is_a_feature() -> None:
    candidates, evidence = _scene()
    rows, _ = _features(candidates, evidence, 30.0)
    expected = as_strong_per_frame(candidates[0].frame, candidates[0].snr, 30.0)
    np.testing.assert_allclose(_col(rows, "as_strong_per_frame_log"), np.log(expected))


def test_the_faint_one_of_a_crowded_pair_knows_its_stronger_neighbour() -> None:
    """Frame 0: a 20 sigma spot, a 5 sigma one 2 px from it and a 10 sigma one 4 px from
    it across the seam; frame 1: the 5 sigma spot alone but for a stronger one just out
    of reach, and a tie of two 7 sigma spots (neither is stronger)."""
    out_of_reach = 4.0 + BRIGHTER_NEIGHBOUR_PX + 0.5
    frame = [0, 0, 0, 1, 1, 1, 1]
    x = [2.0, 4.0, 638.0, 4.0, out_of_reach, 300.0, 301.0]
    y = [50.0, 50.0, 50.0, 50.0, 50.0, 80.0, 80.0]
    snr = [20.0, 5.0, 10.0, 5.0, 30.0, 7.0, 7.0]
    det = Detections.from_columns(frame, x, y, snr=snr)
    share, distance = brighter_neighbours(det, WIDTH)
    np.testing.assert_allclose(share[:3], [np.nan, np.log(5 / 20), np.log(10 / 20)])
    np.testing.assert_allclose(distance[:3], [np.nan, 2.0, 4.0])
    assert np.isnan(share[3:]).all() and np.isnan(distance[3:]).all()


def test_links_join_both_cameras_rows_by_light_curve_and_stereo_match() -> None:
    track = np.array([[4.0 + 0.02 * i, 3.0, 1.0] for i in range(3)])
    lone = np.array([[-2.0, -5.0, 0.5]])
    det1, ev1 = _camera([10, 11, 12, 40], np.vstack([track, lone]), [9, 9, 9, 9], [0.9] * 4, 1)
    det2, ev2 = _camera([10, 11, 12], track, [9, 9, 9], [0.9] * 3, 2)
    matches = stereo_matches((det1, det2), 0, POSE, WIDTH, SEPARATION, GATES)
    links = candidate_links((det1, det2), (ev1, ev2), matches, WIDTH, 30.0)
    assert links.partner.tolist() == [4, 5, 6, -1, 0, 1, 2]
    curve = links.light_curve
    assert len(set(curve[:3])) == 1 and len(set(curve[4:])) == 1  # one light curve each
    assert len(set(curve[[0, 3, 4]])) == 3  # distinct across cameras and spots


def test_relayed_probabilities_carry_the_best_of_a_light_curve_and_of_its_match() -> None:
    # Camera 1: rows 0-2 one light curve (label 0), row 3 alone (label 1); camera 2:
    # rows 4-5 one light curve (label 2), matched with rows 1 and 2.
    links = links_apart(np.array([0, 0, 0, 1, 2, 2]), np.array([-1, 4, 5, -1, 1, 2]))
    p = np.array([0.2, 0.3, 0.9, 0.6, 0.4, 0.1])
    out = relayed_probabilities(p, links)
    assert out.shape == (6, len(RELAYED))
    partner, curve, pair, neighbour = out.T
    np.testing.assert_array_equal(partner, [np.nan, 0.4, 0.1, np.nan, 0.3, 0.9])
    np.testing.assert_array_equal(curve, [0.9, 0.9, 0.9, 0.6, 0.4, 0.4])
    # Row 0 is unmatched in its frame, but its light curve is matched with label 2.
    np.testing.assert_array_equal(pair, [0.4, 0.4, 0.4, np.nan, 0.9, 0.9])
    assert np.isnan(neighbour).all()  # every row a minute from the others


def _bearing(azimuth_deg: float) -> list[float]:
    a = np.radians(azimuth_deg)
    return [float(np.cos(a)), float(np.sin(a)), 0.0]


def test_a_firefly_s_other_flashes_vouch_for_a_doubtful_one() -> None:
    # One row per light curve: (recording, time s, azimuth deg, first-pass probability).
    r, w, g = NEIGHBOUR_RADIUS_DEG, NEIGHBOUR_WINDOW_S, NEIGHBOUR_MIN_GAP_S
    curves = [
        (0, 1.0, 0.0, 0.9),  # 0: a confident flash
        (0, 2.0, r / 2, 0.3),  # 1: the firefly's next flash, in doubt
        (0, 1.0 + g / 2, 0.0, 0.5),  # 2: clutter right after flash 0: the same flash
        (0, 2.0, 1.5 * r, 0.95),  # 3: a flash too far away
        (1, 2.0, r / 2, 0.99),  # 4: the other camera: another recording
        (0, 2.0, r / 2 + 0.5, 0.05),  # 5: too unlikely to vouch for anyone
        (0, 1.0 + 1.5 * w, 0.0, 0.8),  # 6: too late
    ]
    sequence, time_s, azimuth, p = (np.array(c) for c in zip(*curves, strict=True))
    n = len(curves)
    links = CandidateLinks(
        light_curve=np.arange(n),
        partner=np.full(n, -1),
        sequence=sequence.astype(np.intp),
        time_s=time_s,
        bearing=np.array([_bearing(a) for a in azimuth]),
    )
    neighbour = neighbour_probabilities(p, p, links)  # one row a light curve
    # 1 is vouched for by 0 and by 2; 0 and 2 by 1; 5, though unlikely, by 0 and 2.
    np.testing.assert_array_equal(neighbour, [0.3, 0.9, 0.3, np.nan, np.nan, 0.9, np.nan])


def test_a_light_curve_is_placed_at_its_most_probable_row() -> None:
    # Light curve 0 wanders from the confident flash's spot (row 2) to a row in doubt
    # far away; light curve 1, a second later, is near the confident row only.
    r = NEIGHBOUR_RADIUS_DEG
    links = CandidateLinks(
        light_curve=np.array([0, 0, 0, 1]),
        partner=np.full(4, -1),
        sequence=np.zeros(4, np.intp),
        time_s=np.array([1.0, 1.03, 1.07, 2.0]),
        bearing=np.array([_bearing(3 * r), _bearing(2 * r), _bearing(0.0), _bearing(r / 2)]),
    )
    p = np.array([0.2, 0.3, 0.9, 0.4])
    neighbour = neighbour_probabilities(p, np.array([0.9, 0.4]), links)
    np.testing.assert_array_equal(neighbour, [0.4, 0.9])


def test_only_neighbours_the_other_camera_saw_vouch_when_confirmed() -> None:
    # Camera 1: a confident light curve (0) the other camera matched with a doubtful one
    # (2), clutter as confident that camera 2 never saw (1), and a flash in doubt (3) a
    # second after both, beside them.
    r = NEIGHBOUR_RADIUS_DEG
    links = CandidateLinks(
        light_curve=np.array([0, 1, 3, 2]),
        partner=np.array([3, -1, -1, 0]),
        sequence=np.array([0, 0, 0, 1]),
        time_s=np.array([1.0, 1.0, 2.0, 1.0]),
        bearing=np.array([_bearing(0.0), _bearing(r / 4), _bearing(r / 2), _bearing(0.0)]),
    )
    p = np.array([0.9, 0.95, 0.3, 0.6])
    (confirmed,) = relayed_probabilities(p, links, ("confirmed_neighbour_flash_probability",)).T
    # A neighbour vouches as much as the lesser of its own light curve and the other
    # camera's matched one: 0 by min(0.9, 0.6); the clutter, more confident, not at all.
    assert confirmed[2] == 0.6
    # The flash in doubt vouches for nobody: it was not matched either.
    assert np.isnan(confirmed[[0, 1]]).all()
