from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import ArrayLike

from pipeline.params import LinkingParams
from pipeline.trajectories import Linking, _greedy_one_to_one, link
from pipeline.triangulate import Points3D

FPS = 30.0


def points_of(xyz: ArrayLike, frame: ArrayLike) -> Points3D:
    """Points3D sorted by frame (stable), as `triangulate` returns them."""
    xyz, frame = np.asarray(xyz, dtype=float).reshape(-1, 3), np.asarray(frame)
    order = np.argsort(frame, kind="stable")
    return Points3D(
        xyz=xyz[order],
        frame=frame[order].astype(np.int64),
        gap_m=np.zeros(len(frame)),
        range_m=np.linalg.norm(xyz[order], axis=1),
        range_sd_m=np.zeros(len(frame)),
        index1=order,  # the input row, to check labels against the truth
        index2=order,
    )


def flash(
    start: ArrayLike, velocity: ArrayLike, first: int, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Positions (m) and frames of one flash lasting ``n`` frames, moving at ``velocity``
    metres per frame."""
    k = np.arange(n)
    return np.asarray(start) + k[:, None] * np.asarray(velocity), first + k


def test_two_crossing_streaks_stay_apart() -> None:
    # A moves along x, B along y, 5 cm above; they cross at frame 10.
    a_xyz, a_frame = flash([-1.0, 0, 1], [0.1, 0, 0], 0, 21)
    b_xyz, b_frame = flash([0, -1.0, 1.05], [0, 0.1, 0], 0, 21)
    points = points_of(np.vstack([a_xyz, b_xyz]), np.r_[a_frame, b_frame])
    result = link(points, FPS)
    on_a = points.index1 < 21
    assert result.n_streaks == 2
    assert len(np.unique(result.streak_id[on_a])) == 1
    assert len(np.unique(result.streak_id[~on_a])) == 1
    assert result.streak_id[on_a][0] != result.streak_id[~on_a][0]
    # Both start in frame 0, A's row first: A is streak 0.
    assert result.streak_id[on_a][0] == 0


def sequence(gap_frames: int, jump_m: float = 0.0) -> Points3D:
    """Two 6-frame flashes of one firefly moving 2 cm/frame, ``gap_frames`` apart, the
    second displaced sideways by ``jump_m``."""
    xyz1, frame1 = flash([0, 0, 2], [0.02, 0, 0], 0, 6)
    start2 = xyz1[-1] + [0.02 * gap_frames, jump_m, 0]
    xyz2, frame2 = flash(start2, [0.02, 0, 0], 5 + gap_frames, 6)
    return points_of(np.vstack([xyz1, xyz2]), np.r_[frame1, frame2])


def test_gap_of_half_a_second_joins_one_trajectory() -> None:
    result = link(sequence(gap_frames=15), FPS)
    np.testing.assert_array_equal(result.streak_id, [0] * 6 + [1] * 6)
    np.testing.assert_array_equal(result.trajectory_id, [0] * 12)


@pytest.mark.parametrize(
    ("gap_frames", "jump_m"),
    [(45, 0.0), (9, 1.2)],
    ids=["gap 1.5 s", "jump 1.2 m"],
)
def test_long_gap_or_jump_splits_trajectories(gap_frames: int, jump_m: float) -> None:
    result = link(sequence(gap_frames, jump_m), FPS)
    np.testing.assert_array_equal(result.streak_id, [0] * 6 + [1] * 6)
    np.testing.assert_array_equal(result.trajectory_id, [0] * 6 + [1] * 6)


def test_limits_follow_parameters() -> None:
    params = LinkingParams(max_gap_s=2.0, trajectory_radius_m=1.5)
    assert link(sequence(45), FPS, params).n_trajectories == 1
    assert link(sequence(9, 1.2), FPS, params).n_trajectories == 1
    # A 0.25 m step between frames breaks a streak when the radius is 0.2 m.
    xyz, frame = flash([0, 0, 1], [0.25, 0, 0], 0, 4)
    assert link(points_of(xyz, frame), FPS, LinkingParams(streak_radius_m=0.2)).n_streaks == 4
    assert link(points_of(xyz, frame), FPS).n_streaks == 1


def test_competing_streak_candidates_link_nearest_one_to_one() -> None:
    # Frame 0: one point. Frame 1: two points within 0.3 m; the nearer continues the
    # streak, the other starts a new one (but may join as a trajectory).
    points = points_of([[0, 0, 1], [0.25, 0, 1], [0.1, 0, 1]], [0, 1, 1])
    result = link(points, FPS)
    np.testing.assert_array_equal(result.streak_id, [0, 1, 0])
    # Two points in frame 0 compete for one in frame 1: the nearer wins.
    points = points_of([[0.2, 0, 1], [0, 0, 1], [0.05, 0, 1]], [0, 0, 1])
    result = link(points, FPS)
    np.testing.assert_array_equal(result.streak_id, [0, 1, 1])


def test_competing_trajectory_candidates_best_first_one_to_one() -> None:
    # Two streaks end in frame 0, two start in frame 10 (1 point each).
    # E1 = (0,0,1), E2 = (0.25,0,1); S1 = (0.2,0,1) nearest to both, S2 = (-0.7,0,1).
    # Best first: E2–S1 (0.05 m), then E1–S2 (0.7 m); E1–S1 is refused (S1 taken).
    points = points_of(
        [[0, 0, 1], [0.25, 0, 1], [0.2, 0, 1], [-0.7, 0, 1]],
        [0, 0, 10, 10],
    )
    greedy = link(points, FPS, LinkingParams(ambiguity_ratio=0))
    np.testing.assert_array_equal(greedy.streak_id, [0, 1, 2, 3])
    np.testing.assert_array_equal(greedy.trajectory_id, [0, 1, 1, 0])
    # By default E1–S2 is not made: S1 starts as S2 does, 3.5 × nearer to E1 (E1's
    # firefly may be S1's, and E2's next flash missed). E2–S1 has no such rival.
    np.testing.assert_array_equal(link(points, FPS).trajectory_id, [0, 1, 1, 2])


def swarm_beat(rng: np.random.Generator, n: int, missed: set[tuple[int, int]]) -> Points3D:
    """``n`` fireflies 0.3 m apart on a line flashing together (3-frame flashes in frames
    0–2, then 15–17, moving 2 cm between), but for the ``(firefly, first frame)``
    flashes `missed`. ``index1 // 100`` is each point's firefly."""
    xyz, frames, rows = [], [], []
    for i in range(n):
        for start in (0, 15):
            if (i, start) not in missed:
                at = np.array([0.3 * i, 0.0, 3.0]) + (
                    0.02 * rng.standard_normal(3) if start else 0.0
                )
                xyz.append(np.repeat(at[None], 3, axis=0))
                frames.append(start + np.arange(3))
                rows.append(100 * i + start + np.arange(3))
    points = points_of(np.vstack(xyz), np.concatenate(frames))
    return replace(points, index1=np.concatenate(rows)[points.index1])


def mixes_fireflies(points: Points3D, trajectory_id: np.ndarray) -> bool:
    firefly = points.index1 // 100
    pairs = np.unique(np.column_stack([trajectory_id, firefly]), axis=0)
    return len(pairs) > len(np.unique(trajectory_id))


def test_a_firefly_whose_next_flash_is_missed_does_not_take_a_neighbours() -> None:
    # Firefly 0's second flash and firefly 1's first were missed: the nearest free
    # candidate of firefly 0's flash is firefly 1's second, 0.3 m on.
    points = swarm_beat(np.random.default_rng(1), 5, missed={(0, 15), (1, 0)})
    greedy = link(points, FPS, LinkingParams(ambiguity_ratio=0))
    assert mixes_fireflies(points, greedy.trajectory_id) and greedy.n_ambiguous == 0
    result = link(points, FPS)
    assert not mixes_fireflies(points, result.trajectory_id) and result.n_ambiguous > 0
    # The three fireflies seen twice keep their two flashes together.
    assert result.n_trajectories == 5
    # A lone firefly's flash 0.6 m on is linked: nothing else flashed then.
    lone = points_of(
        np.r_[np.zeros((3, 3)), np.full((3, 3), [0.6, 0, 0])], np.r_[0, 1, 2, 15, 16, 17]
    )
    assert link(lone, FPS).n_trajectories == 1


def test_a_firefly_s_later_flashes_are_not_rivals_of_its_next() -> None:
    # One firefly flashing every 0.3 s, drifting 5 cm a beat: every later flash within
    # the 1 s gap is a candidate, but of another moment; the chain is whole.
    xyz = np.repeat(0.05 * np.arange(4)[:, None] * [1, 0, 0], 3, axis=0)
    frame = (9 * np.arange(4)[:, None] + np.arange(3)).ravel()
    assert link(points_of(xyz, frame), FPS).n_trajectories == 1
    # Two flashes starting 2 frames apart, 0.1 and 0.25 m from a streak's end, are
    # rivals for it (within 0.1 s): neither is linked. With a window of 0.05 s they are
    # not rivals, and the nearer one is.
    s1 = flash([0.1, 0, 1], [0, 0, 0], 10, 5)
    s2 = flash([0.25, 0, 1], [0, 0, 0], 12, 5)
    points = points_of(np.r_[[[0, 0, 1]], s1[0], s2[0]], np.r_[0, s1[1], s2[1]])
    assert link(points, FPS).n_trajectories == 3
    narrow = link(points, FPS, LinkingParams(ambiguity_window_s=0.05))
    assert narrow.n_trajectories == 2
    assert narrow.trajectory_id[points.index1 == 0] == narrow.trajectory_id[points.index1 == 1]


def test_nearest_in_space_wins_and_time_breaks_ties() -> None:
    # One streak ends in frame 0; candidates start 0.6 m away after 0.1 s, or 0.5 m
    # away after 0.9 s (and 1.1 m from the first): the nearer one is taken.
    points = points_of([[0, 0, 1], [0.6, 0, 1], [-0.5, 0, 1]], [0, 3, 27])
    np.testing.assert_array_equal(link(points, FPS).trajectory_id, [0, 1, 0])
    # At equal distances the earlier start wins (the later one is 1.2 m from it).
    points = points_of([[0, 0, 1], [0.6, 0, 1], [-0.6, 0, 1]], [0, 27, 3])
    np.testing.assert_array_equal(link(points, FPS).trajectory_id, [0, 0, 1])


def test_ids_contiguous_in_order_of_first_appearance_and_empty_input() -> None:
    rng = np.random.default_rng(0)
    frame = np.sort(rng.integers(0, 300, 400))
    points = points_of(rng.uniform(0, 20, (400, 3)), frame)
    result = link(points, FPS)
    for ids in (result.streak_id, result.trajectory_id):
        _, first = np.unique(ids, return_index=True)
        np.testing.assert_array_equal(np.unique(ids), np.arange(ids.max() + 1))
        assert np.all(np.diff(first) > 0)
    # Each streak holds at most one point per frame and lives in one trajectory.
    pairs = np.unique(np.column_stack([result.streak_id, points.frame]), axis=0)
    assert len(pairs) == len(points)
    streak_trajectory = np.unique(np.column_stack([result.streak_id, result.trajectory_id]), axis=0)
    assert len(streak_trajectory) == result.n_streaks
    empty = link(points.select(np.zeros(len(points), dtype=bool)), FPS)
    assert isinstance(empty, Linking) and len(empty.streak_id) == 0
    assert empty.n_streaks == empty.n_trajectories == 0


def test_bad_fps_raises() -> None:
    with pytest.raises(ValueError, match="fps"):
        link(sequence(15), 0.0)


def test_round_based_greedy_equals_sequential_greedy() -> None:
    rng = np.random.default_rng(1)
    src, dst = rng.integers(0, 60, 400), rng.integers(0, 60, 400)
    cost = rng.integers(0, 50, 400).astype(float)  # many ties: broken by input order
    got = set(zip(*_greedy_one_to_one(src, dst, cost), strict=True))
    expected, used_src, used_dst = set(), set(), set()
    for i in np.lexsort((np.arange(400), cost)):
        if src[i] not in used_src and dst[i] not in used_dst:
            expected.add((src[i], dst[i]))
            used_src.add(src[i])
            used_dst.add(dst[i])
    assert got == expected
