"""Benchmark of stages 4–7 (delay, pose, triangulation, linking) on a long synthetic night.

Synthesises, without video, ~10⁵ frames of two side-by-side 360° cameras watching
fireflies on smooth random flights that emit trains of flashes, projects the flashes
with `pipeline.geometry` (pixel noise, per-camera occlusions, false detections and a few
light-pollution bursts), then times `estimate_delay`, `calibration_pairs` +
`estimate_pose`, `triangulate` and `link`. Prints each stage's seconds (and as a
multiple of a fixed numpy workload timed in the same run, to compare machines), the
total, peak traced memory, and the recovered delay / pose errors and match quality.

Run: ``.venv/bin/python bench/bench_stages.py [--frames 100000] [--seed 0]``
"""

from __future__ import annotations

import argparse
import resource
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.detections import Detections
from pipeline.geometry import Pose, angle_between, bearing_to_pixel, rotation_angle
from pipeline.pose import PoseEstimate, calibration_pairs, estimate_pose
from pipeline.sync import DelayEstimate, estimate_delay
from pipeline.trajectories import Linking, link
from pipeline.triangulate import Points3D, triangulate

FPS = 60.0
WIDTH = 3840
SEPARATION_M = 1.5
DELAY_FRAMES = 1234
PIXEL_NOISE = 0.5
OCCLUSION = 0.05
FALSE_RATE = 0.05


@dataclass(frozen=True)
class Night:
    """Synthetic detections of both cameras with their ground truth."""

    det1: Detections
    det2: Detections
    #: Flash event of each detection (-1: false detection or light pollution).
    event1: np.ndarray
    event2: np.ndarray
    #: Firefly of each flash event.
    firefly: np.ndarray
    pose: Pose
    n_frames: int


def synthesise(n_frames: int, rng: np.random.Generator) -> Night:
    """Fireflies on smooth flights, flash trains, two cameras, noise and outliers."""
    n_fireflies = 40
    # Flights: a centre 3–11 m away plus three slow sinusoids per axis (≤ 2.4 m).
    azimuth = rng.uniform(0, 2 * np.pi, n_fireflies)
    distance = rng.uniform(3.0, 11.0, n_fireflies)
    centre = np.column_stack(
        [distance * np.cos(azimuth), distance * np.sin(azimuth), rng.uniform(0, 2, n_fireflies)]
    )
    amplitude = rng.uniform(0.2, 0.8, (n_fireflies, 3, 3))
    omega = 2 * np.pi / (rng.uniform(10, 60, (n_fireflies, 3, 3)) * FPS)
    phase = rng.uniform(0, 2 * np.pi, (n_fireflies, 3, 3))

    # Flash trains: Poisson onsets, 3–8 flashes 0.4–0.9 s apart, each 3–8 frames long.
    n_trains = int(n_frames / FPS * n_fireflies / 20)
    train_firefly = rng.integers(0, n_fireflies, n_trains)
    train_onset = rng.uniform(-DELAY_FRAMES, n_frames, n_trains)
    per_train = rng.integers(3, 9, n_trains)
    period = rng.uniform(0.4, 0.9, n_trains) * FPS
    firefly = np.repeat(train_firefly, per_train)
    rank = np.arange(per_train.sum()) - np.repeat(np.cumsum(per_train) - per_train, per_train)
    onset = np.floor(np.repeat(train_onset, per_train) + rank * np.repeat(period, per_train))
    duration = rng.integers(3, 9, len(onset))
    event = np.repeat(np.arange(len(onset)), duration)
    frame = (np.repeat(onset, duration) + _ranks(duration)).astype(np.int64)
    waves = amplitude[firefly[event]] * np.sin(
        omega[firefly[event]] * frame[:, None, None] + phase[firefly[event]]
    )
    xyz = centre[firefly[event]] + waves.sum(axis=2)

    pose = Pose(
        Rotation.from_rotvec(np.radians([0.8, -1.5, 2.5])).as_matrix(), np.array([0.05, 1, 0.02])
    )
    det1, event1 = _camera(xyz, frame, event, n_frames, rng)
    det2, event2 = _camera(
        pose.world_to_camera2(xyz, SEPARATION_M), frame + DELAY_FRAMES, event, n_frames, rng
    )
    return Night(det1, det2, event1, event2, firefly, pose, n_frames)


def _camera(
    xyz: np.ndarray, frame: np.ndarray, event: np.ndarray, n_frames: int, rng: np.random.Generator
) -> tuple[Detections, np.ndarray]:
    """Noisy pixel detections of one camera plus false ones and light pollution."""
    seen = (frame >= 0) & (frame < n_frames) & (rng.random(len(frame)) > OCCLUSION)
    u, v = bearing_to_pixel(xyz[seen], WIDTH)
    u = np.mod(u + rng.normal(0, PIXEL_NOISE, len(u)), WIDTH)
    v = v + rng.normal(0, PIXEL_NOISE, len(v))
    n_false = int(FALSE_RATE * seen.sum())
    # Three bursts of light pollution: 2 s of 20–60 detections per frame.
    starts = rng.integers(0, n_frames - 120, 3)
    burst = np.repeat((starts[:, None] + np.arange(120)).ravel(), rng.integers(20, 60, 360))
    extra_frame = np.r_[rng.integers(0, n_frames, n_false), burst]
    det = Detections.from_columns(
        np.r_[frame[seen], extra_frame],
        np.r_[u, rng.uniform(0, WIDTH, len(extra_frame))],
        np.r_[v, rng.uniform(0, WIDTH / 2, len(extra_frame))],
    )
    truth = np.r_[event[seen], np.full(len(extra_frame), -1)]
    order = np.argsort(det.frame, kind="stable")
    return det.select(order), truth[order]


def _ranks(counts: np.ndarray) -> np.ndarray:
    """0, 1, …, c−1 for each count c, concatenated."""
    return np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)


def baseline_seconds() -> float:
    """A fixed numpy workload (sorts and FFTs), the yardstick for this machine."""
    rng = np.random.default_rng(0)
    data = rng.random(2_000_000)
    start = time.perf_counter()
    for _ in range(3):
        np.sort(data)
        np.fft.rfft(data)
    return time.perf_counter() - start


def timed(results: dict[str, float], name: str, func: Callable[[], Any]) -> Any:
    start = time.perf_counter()
    out = func()
    results[name] = time.perf_counter() - start
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    night = synthesise(args.frames, np.random.default_rng(args.seed))
    print(
        f"{night.n_frames} frames at {FPS:g} fps, width {WIDTH}: "
        f"{len(night.det1)} detections in camera 1, {len(night.det2)} in camera 2"
    )
    base = baseline_seconds()
    seconds: dict[str, float] = {}
    tracemalloc.start()
    counts1 = night.det1.counts_per_frame(night.n_frames)
    counts2 = night.det2.counts_per_frame(night.n_frames)
    delay = timed(seconds, "sync", lambda: estimate_delay(counts1, counts2, FPS))
    pairs = timed(
        seconds,
        "calibration pairs",
        lambda: calibration_pairs(night.det1, night.det2, delay.delay_frames, WIDTH),
    )
    pose = timed(seconds, "pose", lambda: estimate_pose(pairs))
    points = timed(
        seconds,
        "triangulate",
        lambda: triangulate(
            night.det1, night.det2, delay.delay_frames, pose.pose, WIDTH, SEPARATION_M
        ),
    )
    linking = timed(seconds, "link", lambda: link(points, FPS))
    peak_traced = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()

    print(f"\nbaseline workload: {base:.3f} s")
    print(f"{'stage':<20}{'seconds':>10}{'× baseline':>12}")
    for name, value in seconds.items():
        print(f"{name:<20}{value:>10.3f}{value / base:>12.1f}")
    total = sum(seconds.values())
    print(f"{'total':<20}{total:>10.3f}{total / base:>12.1f}")
    print(
        f"peak traced memory in the stages: {peak_traced / 2**20:.0f} MiB; "
        f"process max RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**10:.0f} MiB"
    )
    report_accuracy(night, delay, pose, points, linking)


def report_accuracy(
    night: Night,
    delay: DelayEstimate,
    pose: PoseEstimate,
    points: Points3D,
    linking: Linking,
) -> None:
    print(
        f"\ndelay: {delay.delay_frames} frames (truth {DELAY_FRAMES}), "
        f"confidence {delay.confidence:.2f}"
    )
    rot = np.degrees(rotation_angle(pose.pose.rotation, night.pose.rotation))
    trans = np.degrees(angle_between(pose.pose.translation, night.pose.translation))
    print(
        f"pose: {pose.n_inliers}/{pose.n_pairs} inlier pairs, rotation error {rot:.4f}°, "
        f"translation error {trans:.4f}°, median residual {pose.stats['median_deg']:.4f}°"
    )
    e1, e2 = night.event1[points.index1], night.event2[points.index2]
    true_match = (e1 == e2) & (e1 >= 0)
    # A flash event seen by both cameras in a synchronised frame is a point to find.
    key1 = _event_frame_keys(night.event1, night.det1.frame)
    key2 = _event_frame_keys(night.event2, night.det2.frame - DELAY_FRAMES)
    findable = len(np.intersect1d(key1, key2))
    print(
        f"triangulate: {len(points)} points, {true_match.mean():.1%} true matches, "
        f"recall {true_match.sum() / findable:.1%}, "
        f"median gap {np.median(points.gap_m) * 100:.1f} cm"
    )
    purity = _purity(linking.trajectory_id[true_match], night.firefly[e1[true_match]])
    print(
        f"link: {linking.n_streaks} streaks, {linking.n_trajectories} trajectories "
        f"({len(np.unique(night.firefly))} fireflies); trajectory purity {purity:.1%}"
    )


def _event_frame_keys(event: np.ndarray, frame: np.ndarray) -> np.ndarray:
    real = event >= 0
    return event[real] * (1 << 32) + frame[real]


def _purity(labels: np.ndarray, truth: np.ndarray) -> float:
    """Fraction of points whose trajectory's majority firefly is their own."""
    pairs, n = np.unique(np.column_stack([labels, truth]), axis=0, return_counts=True)
    majority = np.zeros(labels.max() + 1 if len(labels) else 0, dtype=np.int64)
    np.maximum.at(majority, pairs[:, 0], n)
    return float(majority.sum() / max(len(labels), 1))


if __name__ == "__main__":
    main()
