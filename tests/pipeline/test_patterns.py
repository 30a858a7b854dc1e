"""Flash patterns on hand-made streaks with known durations and intervals, and synchrony."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.params import LinkingParams, PatternParams
from pipeline.patterns import (
    flashes_from_streaks,
    group_quantiles,
    night_patterns,
    per_trajectory,
    synchrony,
)
from pipeline.trajectories import link
from pipeline.triangulate import Points3D

FPS = 30.0


def streaks(trains: list[tuple[int, int, list[int], int]]) -> dict[str, np.ndarray]:
    """Rows of a trajectories table: (trajectory, first onset frame, per-flash lengths in
    frames, onset spacing in frames); positions move 0.1 m per frame along x."""
    columns: dict[str, list] = {k: [] for k in ("trajectory_id", "streak_id", "frame")}
    streak = 0
    for trajectory, start, lengths, spacing in trains:
        for k, length in enumerate(lengths):
            frames = start + k * spacing + np.arange(length)
            columns["frame"] += frames.tolist()
            columns["trajectory_id"] += [trajectory] * length
            columns["streak_id"] += [streak] * length
            streak += 1
    table = {k: np.asarray(v, dtype=np.int64) for k, v in columns.items()}
    n = len(table["frame"])
    table["x"] = table["frame"] * 0.1
    table["y"] = np.zeros(n)
    table["z"] = np.full(n, 0.5)
    return table


def test_durations_intervals_and_trains_of_hand_made_streaks() -> None:
    # Trajectory 7: a train of 4 flashes (3, 5, 5, 7 frames) every 15 frames, then after a
    # 3 s pause a second train of 2 flashes every 20 frames. Trajectory 9: one 4-frame flash.
    table = streaks([(7, 10, [3, 5, 5, 7], 15), (7, 10 + 45 + 90, [4, 4], 20), (9, 50, [4], 1)])
    params = PatternParams()
    flashes, night = night_patterns(table, FPS, 400, params)
    assert len(flashes) == 7
    durations = np.array([3, 5, 5, 7, 4, 4, 4]) / FPS
    assert night["flash_duration_s"]["median"] == pytest.approx(np.median(durations))
    assert night["flash_duration_s"]["q25"] == pytest.approx(np.quantile(durations, 0.25))
    intervals = np.array([15, 15, 15, 20]) / FPS  # the 3.5 s gap is between trains
    assert night["ifi_s"]["median"] == pytest.approx(np.median(intervals))
    assert night["ifi_s"]["n"] == 4
    assert night["ifi_s"]["mode"] == pytest.approx(15 / FPS)
    assert night["n_trains"] == 3
    rows = per_trajectory(table, flashes, FPS, params, camera_height_m=1.5)
    assert rows["trajectory_id"].tolist() == [7, 9]
    assert rows["n_flashes"].tolist() == [6, 1]
    assert rows["n_trains"].tolist() == [2, 1]
    assert rows["flash_duration_median_s"] == pytest.approx([4.5 / FPS, 4 / FPS])
    assert rows["ifi_median_s"][0] == pytest.approx(15 / FPS)
    assert np.isnan(rows["ifi_median_s"][1])
    assert rows["mean_height_m"] == pytest.approx([2.0, 2.0])
    # x moves 0.1 m per frame: the path through the points is 0.1 m per frame elapsed.
    span = rows["last_frame"] - rows["first_frame"]
    assert rows["path_length_m"] == pytest.approx(span * 0.1)
    assert rows["mean_speed_mps"][0] == pytest.approx(0.1 * FPS)
    assert np.isnan(per_trajectory(table, flashes, FPS, params, None)["mean_height_m"]).all()


def test_a_missed_frame_mid_flash_does_not_split_it() -> None:
    # One flash of 6 frames whose 3rd frame was lost: two streaks, one flash.
    frame = np.array([100, 101, 103, 104, 105, 106])
    streak = np.array([0, 0, 1, 1, 1, 1])
    joined = flashes_from_streaks(np.zeros(6, dtype=np.int64), streak, frame, join_gap_frames=1)
    assert joined.n_frames.tolist() == [7]
    split = flashes_from_streaks(np.zeros(6, dtype=np.int64), streak, frame, join_gap_frames=0)
    assert split.n_frames.tolist() == [2, 4]


def test_flashes_cut_by_the_recording_are_left_out_of_durations() -> None:
    table = streaks([(1, 0, [2], 1), (2, 40, [5], 1), (3, 96, [4], 1)])
    flashes, night = night_patterns(table, FPS, 100, PatternParams())
    assert flashes.censored.tolist() == [True, False, True]
    assert night["flash_duration_s"]["n"] == 1
    assert night["flash_duration_s"]["median"] == pytest.approx(5 / FPS)


def test_group_quantiles_match_numpy() -> None:
    rng = np.random.default_rng(0)
    groups = rng.integers(0, 30, 500)
    values = rng.normal(size=500)
    values[::17] = np.nan
    ids, q = group_quantiles(groups, values, (0.25, 0.5, 0.9))
    for row, g in enumerate(ids):
        sample = values[(groups == g) & np.isfinite(values)]
        assert q[row] == pytest.approx(np.quantile(sample, [0.25, 0.5, 0.9]))


def swarm(rng: np.random.Generator, synchronous: bool, n_frames: int) -> dict[str, np.ndarray]:
    """40 fireflies flashing 4-frame flashes in trains of 5, 15 frames (0.5 s) apart: all
    on one collective beat, or each at its own random phase and period."""
    trains = []
    for trajectory in range(40):
        start = int(rng.integers(0, n_frames - 120))
        if synchronous:
            start -= start % 15  # on the swarm's beat
            spacing = 15
        else:
            spacing = int(rng.integers(12, 19))
        trains.append((trajectory, start, [4] * 5, spacing))
    return streaks(trains)


@pytest.mark.parametrize("synchronous", [True, False])
def test_synchrony_is_found_only_when_fireflies_flash_together(synchronous: bool) -> None:
    n_frames = 1800
    table = swarm(np.random.default_rng(1), synchronous, n_frames)
    found = synchrony(table["frame"], table["trajectory_id"], n_frames, FPS, PatternParams())
    assert found["synchronous"] is synchronous
    # Every firefly repeats itself: the count series is periodic either way.
    assert found["count_period_s"] == pytest.approx(0.5, abs=0.1)
    if synchronous:
        assert found["period_s"] == pytest.approx(0.5, abs=1 / FPS)
        assert found["strength"] > 0.3
    else:
        assert found["strength"] < PatternParams().min_sync_strength or found["z"] < 4


def test_too_few_trajectories_for_a_synchrony_test() -> None:
    table = streaks([(1, 10, [4] * 5, 15), (2, 300, [4] * 5, 15)])
    _, night = night_patterns(table, FPS, 900, PatternParams())
    assert night["synchronous"] is None
    assert night["ifi_s"]["median"] == pytest.approx(0.5)


def test_a_real_synchronous_swarm_is_found_synchronous(shared_dir: Path) -> None:
    """Photinus carolinus in a tent (Sarfati et al. 2020; 60 fps, 30 min): flashes every
    ~0.55 s in synchronous bursts. Linked with the pipeline's own linking, as a run would."""
    data = np.loadtxt(shared_dir / "data/real-3d/xyzt_tent.csv", delimiter=",")
    data = data[np.argsort(data[:, 3], kind="stable")]
    frame = data[:, 3].astype(np.int64)
    n = len(frame)
    index = np.arange(n)
    points = Points3D(
        data[:, :3],
        frame,
        np.zeros(n),
        np.linalg.norm(data[:, :3], axis=1),
        np.zeros(n),
        index,
        index,
    )
    linking = link(points, 60.0, LinkingParams())
    table = {
        "x": data[:, 0],
        "y": data[:, 1],
        "z": data[:, 2],
        "frame": frame,
        "streak_id": linking.streak_id,
        "trajectory_id": linking.trajectory_id,
    }
    _, night = night_patterns(table, 60.0, int(frame.max()) + 1, PatternParams())
    assert night["synchronous"] is True
    assert 0.5 <= night["period_s"] <= 0.65
    assert night["ifi_s"]["median"] == pytest.approx(night["period_s"], abs=2 / 60)
    assert night["strength"] > 0.3
    assert 0.05 < night["flash_duration_s"]["median"] < 0.2
