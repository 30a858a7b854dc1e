"""Acceptance of flash candidates from every kind of evidence (pipeline.acceptance)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pipeline.acceptance import (
    Evidence,
    Verdict,
    assess,
    confirm,
    refined,
    spot_chains,
    steady_frames,
)
from pipeline.detections import Detections
from pipeline.geometry import Pose, bearing_to_pixel
from pipeline.params import AcceptanceParams, FlickerParams, LinkingParams, TriangulationParams
from pipeline.refine import refine_positions
from pipeline.trajectories import link
from pipeline.triangulate import triangulate

WIDTH, FPS, SEPARATION = 640, 60.0, 1.5
POSE = Pose(np.eye(3), [1.0, 0.0, 0.0])
THRESHOLD = 0.7


def _candidates(rows: list[tuple[int, float, float, float, float]]) -> Detections:
    frame, x, y, probability, snr = (np.array(c) for c in zip(*rows, strict=True))
    return Detections.from_columns(frame, x, y, flash_probability=probability, snr=snr)


def _flash(start: int, x: float, y: float, frames: int, probability: float, snr: float):
    return [(start + i, x + 0.2 * i, y, probability, snr) for i in range(frames)]


def test_a_lit_spot_is_measured_frame_span_of_its_chain() -> None:
    frame = np.array([10, 11, 12, 13, 40, 41, 100, 101, 102])
    x = np.array([100.0, 100.4, 100.8, 101.2, 639.5, 0.3, 300.0, 310.0, 320.0])
    y = np.array([50.0, 50.0, 50.2, 50.1, 80.0, 80.0, 60.0, 60.0, 60.0])
    chain = spot_chains(frame, x, y, WIDTH, radius_deg=1.0)  # 1° = 1.8 px here
    lit = steady_frames(frame, chain)
    assert lit.tolist() == [4, 4, 4, 4, 2, 2, 1, 1, 1]  # across the seam; jumps break it
    assert len(set(chain[:4])) == 1 and chain[4] == chain[5] and len(set(chain)) == 5


def test_positions_are_refined_along_the_light_curve_only_when_asked() -> None:
    rng = np.random.default_rng(8)
    frame = np.r_[np.arange(8), 30]
    x = np.r_[200.0 + 0.3 * np.arange(8), 400.0] + rng.normal(0, 0.3, 9)
    y = np.r_[100.0 - 0.1 * np.arange(8), 50.0] + rng.normal(0, 0.3, 9)
    snr = np.r_[np.linspace(5, 20, 8), 9.0]
    candidates = Detections.from_columns(frame, x, y, snr=snr)
    params = AcceptanceParams()  # 0.07 s: ±4 frames at 60 fps
    out = refined(candidates, WIDTH, FPS, params)
    chain = spot_chains(frame, x, y, WIDTH, params.radius_deg)
    weight = candidates.snr.astype(np.float64) ** 2
    want_x, want_y = refine_positions(frame, x, y, weight, chain, WIDTH, 4)
    np.testing.assert_array_equal(out.x, want_x)
    np.testing.assert_array_equal(out.y, want_y)
    assert not np.allclose(out.x[:8], x[:8]) and out.x[8] == x[8]
    assert np.array_equal(out.frame, frame) and np.array_equal(out.snr, candidates.snr)
    off = refined(candidates, WIDTH, FPS, params.model_copy(update={"position_window_s": 0.0}))
    assert np.array_equal(off.x, x) and np.array_equal(off.y, y)


def test_each_kind_of_evidence_gives_its_verdict() -> None:
    rng = np.random.default_rng(4)
    rows = [
        *_flash(0, 100, 50, 5, 0.95, 20.0),  # confident
        *_flash(100, 200, 60, 5, 0.4, 20.0),  # the classifier is unsure: doubtful
        *_flash(200, 300, 70, 5, 0.95, 5.0),  # faint: doubtful
        *_flash(300, 400, 80, 5, 0.01, 30.0),  # the classifier says no
        *_flash(400, 500, 90, 90, 0.95, 30.0),  # lit 1.5 s: a lamp
    ]
    # Moonlight through leaves: the same spot lit in 70 % of 300 frames, never 31 in a row.
    lit = np.flatnonzero(rng.random(300) < 0.7)
    lit = lit[(lit % 31) != 0]
    rows += [(int(k), 50.0, 150.0, 0.95, 20.0) for k in lit + 600]
    candidates = _candidates(rows)
    evidence = assess(candidates, WIDTH, FPS, THRESHOLD, AcceptanceParams(), FlickerParams())
    verdict = evidence.verdict
    assert np.all(verdict[0:5] == Verdict.CONFIDENT)
    assert np.all(verdict[5:15] == Verdict.DOUBTFUL)
    assert np.all(verdict[15:20] == Verdict.CLASSIFIER)
    assert np.all(verdict[20:110] == Verdict.STEADY)
    # (within a second of its ends the flicker window is half empty)
    assert np.all(verdict[110:][60:-60] == Verdict.FLICKER)
    assert evidence.counts()["steady"] == 90 and evidence.lit_frames[20] == 90


def test_a_faint_spot_lit_in_one_frame_only_is_doubtful() -> None:
    rows = [
        *_flash(0, 100, 50, 1, 0.95, 10.0),  # one frame at 10 σ: grain as likely as a flash
        *_flash(100, 200, 60, 1, 0.95, 15.0),  # one frame, bright enough
        *_flash(200, 300, 70, 3, 0.95, 10.0),  # three frames at 10 σ
    ]
    params = AcceptanceParams(confident_snr=8.0, single_frame_snr=12.0)
    verdict = assess(_candidates(rows), WIDTH, FPS, THRESHOLD, params, FlickerParams()).verdict
    expected = [Verdict.DOUBTFUL, Verdict.CONFIDENT] + [Verdict.CONFIDENT] * 3
    assert verdict.tolist() == expected


def _faint(frames: NDArray[np.int64], x: float, y: float, snr: float = 3.5) -> Detections:
    n = len(frames)
    return Detections.from_columns(frames, np.full(n, x), np.full(n, y), snr=np.full(n, snr))


def test_faint_peaks_join_light_curves_but_get_no_verdict() -> None:
    rows = [
        *_flash(100, 200, 60, 5, 0.95, 20.0),  # a wind-held glint, bright for 5 frames...
        *_flash(300, 300, 70, 5, 0.95, 20.0),  # a flash, rising out of and back into grain
        *_flash(500, 400, 80, 1, 0.95, 10.0),  # 10 σ in one frame, faint before and after
    ]
    candidates = _candidates(rows)
    faint = Detections.concat(
        [
            _faint(np.r_[60:100, 105:150], 200.8, 60.0),  # ...and faintly lit 1.5 s around
            _faint(np.r_[298:300, 305:307], 300.5, 70.0),
            _faint(np.r_[498:500, 501:503], 400.2, 80.0),
        ]
    )
    params = AcceptanceParams(confident_snr=8.0, single_frame_snr=12.0)
    alone = assess(candidates, WIDTH, FPS, THRESHOLD, params, FlickerParams())
    assert alone.verdict.tolist() == [Verdict.CONFIDENT] * 10 + [Verdict.DOUBTFUL]
    evidence = assess(candidates, WIDTH, FPS, THRESHOLD, params, FlickerParams(), faint)
    assert len(evidence) == len(candidates)
    assert np.all(evidence.verdict[:5] == Verdict.STEADY) and evidence.lit_frames[0] == 90
    assert np.all(evidence.verdict[5:10] == Verdict.CONFIDENT)
    assert np.all(evidence.lit_frames[5:10] == 9)
    # Grain lights faint peaks too: a candidate in one frame still needs single_frame_snr.
    assert evidence.verdict[10] == Verdict.DOUBTFUL and evidence.lit_frames[10] == 5
    # The chains are the candidates' own with the faint frames bridged in.
    assert len(set(evidence.chain[5:10].tolist())) == 1
    assert evidence.chain[0] != evidence.chain[5] != evidence.chain[10]


def test_faint_peaks_do_not_count_as_flicker() -> None:
    # Grain and sway light faint peaks around many spots; as flicker they cost flashes
    # (tuning nights, docs/detection.md). A flash train over a shimmering spot stays.
    rng = np.random.default_rng(3)
    flashes = np.r_[1000:1005, 1060:1065, 1120:1125]
    train = _candidates([(int(k), 50.0, 150.0, 0.95, 20.0) for k in flashes])
    shimmer = np.setdiff1d(np.flatnonzero(rng.random(200) < 0.7) + 980, flashes)
    params = AcceptanceParams()
    verdict = assess(
        train, WIDTH, FPS, THRESHOLD, params, FlickerParams(), _faint(shimmer, 50.0, 150.0)
    ).verdict
    assert np.all(verdict == Verdict.CONFIDENT)


def test_a_spot_often_as_bright_before_is_rejected_unless_already_rejected() -> None:
    rows = [
        *_flash(0, 100, 50, 3, 0.95, 20.0),  # confident, but its spot recurs
        *_flash(100, 200, 60, 3, 0.4, 20.0),  # doubtful, recurs
        *_flash(200, 300, 70, 3, 0.01, 30.0),  # the classifier said no first
        *_flash(300, 400, 80, 3, 0.95, 20.0),  # recurs a little: a flash
        *_flash(400, 500, 90, 3, 0.95, 20.0),  # not measured (start of a video)
    ]
    frame, x, y, probability, snr = (np.array(c) for c in zip(*rows, strict=True))
    recurrence = np.repeat([0.6, 0.3, 0.9, 0.1, np.nan], 3)
    candidates = Detections.from_columns(
        frame, x, y, flash_probability=probability, snr=snr, recurrence=recurrence
    )
    params = AcceptanceParams(max_recurrence=0.25)
    verdict = assess(candidates, WIDTH, FPS, THRESHOLD, params, FlickerParams()).verdict
    expected = [Verdict.RECURRENT] * 6 + [Verdict.CLASSIFIER] * 3 + [Verdict.CONFIDENT] * 6
    assert verdict.tolist() == expected
    off = AcceptanceParams(max_recurrence=1.01)
    assert (
        Verdict.RECURRENT
        not in assess(candidates, WIDTH, FPS, THRESHOLD, off, FlickerParams()).verdict
    )


def test_without_a_classifier_snr_decides_and_disabled_accepts_all() -> None:
    candidates = _candidates([(0, 10.0, 10.0, np.nan, 12.0), (5, 90.0, 10.0, np.nan, 4.5)])
    evidence = assess(candidates, WIDTH, FPS, None, AcceptanceParams(), FlickerParams())
    assert evidence.verdict.tolist() == [Verdict.CONFIDENT, Verdict.DOUBTFUL]
    off = assess(candidates, WIDTH, FPS, None, AcceptanceParams(enabled=False), FlickerParams())
    assert off.confident.all()


def _seen(points: NDArray[np.float64], camera: int) -> tuple[NDArray, NDArray]:
    local = points if camera == 1 else POSE.world_to_camera2(points, SEPARATION)
    return bearing_to_pixel(local, WIDTH)


def _stereo_scene() -> tuple[tuple[Detections, Detections], tuple[Evidence, Evidence]]:
    """Camera 1 and 2 candidates: a faint firefly over 4 frames (doubtful in both), a
    faint single-frame flash, a confident flash, a faint far firefly over 4 frames whose
    depth noise breaks its 3D links, faint spots that light up one after another 0.25 m
    apart (a 3D streak of three different spots), and unmatched noise in camera 1."""
    track = np.array([[4.0 + 0.02 * i, 3.0, 1.0] for i in range(4)])
    single = np.array([[-3.0, 5.0, 2.0]])
    bright = np.array([[2.0, -6.0, 1.5]])
    # Along one ray of camera 1, 1 m nearer and farther in turn (> linking's 0.3 m).
    far = np.outer([17.5, 18.5, 17.6, 18.4], [0.6, 0.79, 0.1])
    hop = np.array([[3.0, 0.25 * i, -1.0] for i in range(3)])  # 4.5° apart: three spots
    frames = {
        "track": np.arange(10, 14),
        "single": np.array([30]),
        "bright": np.array([50]),
        "far": np.arange(90, 94),
        "hop": np.arange(110, 113),
    }
    dets, evs = [], []
    for camera in (1, 2):
        u, v, f, snr, verdict = [], [], [], [], []
        for name, points, s, kind in (
            ("track", track, 5.0, Verdict.DOUBTFUL),
            ("single", single, 5.0, Verdict.DOUBTFUL),
            ("bright", bright, 30.0, Verdict.CONFIDENT),
            ("far", far, 5.0, Verdict.DOUBTFUL),
            ("hop", hop, 5.0, Verdict.DOUBTFUL),
        ):
            pu, pv = _seen(points, camera)
            u += pu.tolist()
            v += pv.tolist()
            f += frames[name].tolist()
            snr += [s] * len(points)
            verdict += [kind] * len(points)
        if camera == 1:  # noise: a doubtful candidate nothing in camera 2 matches
            u, v, f = [*u, 500.0], [*v, 40.0], [*f, 70]
            snr, verdict = [*snr, 4.5], [*verdict, Verdict.DOUBTFUL]
        det = Detections.from_columns(f, u, v, snr=snr)
        dets.append(det)
        chain = spot_chains(det.frame, det.x, det.y, WIDTH, 1.0)
        evs.append(Evidence(np.array(verdict, np.int8), np.ones(len(det), np.int64), chain))
    return (dets[0], dets[1]), (evs[0], evs[1])


def _confirm(params: AcceptanceParams):
    candidates, evidence = _stereo_scene()
    return confirm(
        candidates,
        evidence,
        0,
        POSE,
        WIDTH,
        SEPARATION,
        params,
        TriangulationParams(),
    )


def test_stereo_confirms_a_faint_streak_but_not_a_faint_single_frame_or_noise() -> None:
    outcome = _confirm(AcceptanceParams())
    # Rows: 4 streak frames, 1 faint single frame, 1 confident flash, 4 far frames,
    # 3 hops (+ noise in cam 1).
    expected = [True] * 4 + [False, True] + [True] * 4 + [False] * 3
    assert outcome.accepted1.tolist() == [*expected, False]
    assert outcome.stereo1.tolist() == [True] * 4 + [False, False] + [True] * 4 + [False] * 4
    assert outcome.accepted2.tolist() == expected


def test_a_3d_streak_of_different_spots_is_not_confirmed() -> None:
    (det1, det2), (ev1, _) = _stereo_scene()
    hop = np.arange(10, 13)
    points = triangulate(
        det1.select(hop), det2.select(hop), 0, POSE, WIDTH, SEPARATION, TriangulationParams()
    )
    assert len(np.unique(link(points, FPS, LinkingParams()).streak_id)) == 1  # one 3D streak
    assert len(np.unique(ev1.chain[hop])) == 3  # ... of three different spots
    assert not _confirm(AcceptanceParams()).stereo1[hop].any()


def test_a_far_flash_is_confirmed_by_its_light_curves_where_its_3d_links_break() -> None:
    (det1, det2), (ev1, ev2) = _stereo_scene()
    far1, far2 = np.arange(6, 10), np.arange(6, 10)
    points = triangulate(
        det1.select(far1), det2.select(far2), 0, POSE, WIDTH, SEPARATION, TriangulationParams()
    )
    assert len(points) == 4
    assert len(np.unique(link(points, FPS, LinkingParams()).streak_id)) == 4  # no 3D streak
    assert len(np.unique(ev1.chain[far1])) == 1 and len(np.unique(ev2.chain[far2])) == 1
    assert _confirm(AcceptanceParams()).stereo2[far2].all()
    # ... but only where the light curves rise to a peak, and span min_streak matches.
    assert not _confirm(AcceptanceParams(streak_peak_snr=5.5)).stereo2[far2].any()
    assert not _confirm(AcceptanceParams(min_streak=5)).stereo2[far2].any()


def test_bright_matches_are_confirmed_without_a_streak_and_stereo_can_be_off() -> None:
    bright = _confirm(AcceptanceParams(stereo_snr=5.0))
    assert bright.accepted1[4] and bright.accepted2[4]  # both stand 5 σ: confirmed
    anchored = _confirm(AcceptanceParams(anchored=True))
    assert not anchored.stereo1.any()  # no confident flash in the faint streak
    off = _confirm(AcceptanceParams(stereo=False))
    assert off.accepted1.tolist() == [False] * 5 + [True] + [False] * 8


def test_imported_detections_are_confident_unless_faint() -> None:
    det = Detections.from_columns([0, 1, 2], [1.0, 2.0, 3.0], [1.0, 1.0, 1.0], snr=[np.nan, 20, 5])
    evidence = Evidence.imported(det, WIDTH, AcceptanceParams(confident_snr=8.0))
    assert evidence.verdict.tolist() == [0, 0, 1]
    # Consecutive frames 1 px apart: one light curve, which stereo can confirm.
    assert evidence.chain.tolist() == [0, 0, 0] and evidence.lit_frames.tolist() == [3, 3, 3]


def test_evidence_round_trips_and_reads_earlier_files_without_chains(tmp_path) -> None:
    duty = np.array([0.1, 0.1, 0.5])
    evidence = Evidence(
        np.array([0, 1, 4], np.int8), np.array([3, 3, 1]), np.array([0, 0, 1]), duty
    )
    evidence.save(tmp_path / "now.npz")
    loaded = Evidence.load(tmp_path / "now.npz")
    assert loaded.verdict.tolist() == [0, 1, 4] and loaded.chain.tolist() == [0, 0, 1]
    np.testing.assert_array_equal(loaded.flicker_duty, duty)
    np.savez_compressed(tmp_path / "earlier.npz", verdict=evidence.verdict, lit_frames=[3, 3, 1])
    earlier = Evidence.load(tmp_path / "earlier.npz")
    assert earlier.chain.tolist() == [0, 1, 2] and earlier.flicker_duty is None
