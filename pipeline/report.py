"""Quality report of a run: PNG plots (the summary is `pipeline.summary`).

Plots: the per-frame flash counts of both cameras aligned by the estimated delay, the
delay votes and cross-correlation, the residuals of the first pose and of its refit
(`pipeline.pose_refit`), the trajectories in 3D (and from above) as lines joining each
trajectory's flashes in time order, and the night's flash pattern
(`pipeline.pattern_plots`).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only: never needs a display
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection
from mpl_toolkits.mplot3d.art3d import Line3DCollection

from pipeline import artifacts
from pipeline.clock import NightClock
from pipeline.detections import Detections
from pipeline.jsonio import read_json
from pipeline.params import PatternParams
from pipeline.pattern_plots import pattern_plots
from pipeline.probe import StereoProbe
from pipeline.results import read_trajectories
from pipeline.triangulate import SURE_RELATIVE_SD, sure_of_range


def write_plots(workdir: Path, patterns: PatternParams | None = None) -> list[str]:
    """Write the report's plots; return their names relative to `workdir`."""
    report_dir = workdir / artifacts.REPORT_DIR
    report_dir.mkdir(parents=True, exist_ok=True)
    probe = StereoProbe.load(workdir)
    sync = read_json(workdir / artifacts.SYNC_JSON)
    det1 = Detections.from_csv(workdir / artifacts.flashes_name(1))
    det2 = Detections.from_csv(workdir / artifacts.flashes_name(2))
    trajectories = read_trajectories(workdir / artifacts.TRAJECTORIES_CSV)
    fits = {
        title: np.load(workdir / name)
        for title, name in (
            ("first pose: confident flashes", artifacts.CALIBRATION_PAIRS_NPZ),
            ("refit: accepted flashes", artifacts.REFIT_PAIRS_NPZ),
        )
        if (workdir / name).exists()  # runs of releases before the refit have no refit pairs
    }

    plots = {
        "counts.png": lambda p: plot_counts(det1, det2, probe.n_frames, probe.fps, sync, p),
        "delay.png": lambda p: plot_delay(sync, probe.fps, p),
        "calibration_residuals.png": lambda p: plot_residuals(fits, p),
        "trajectories_3d.png": lambda p: plot_trajectories(trajectories, p),
        "range_uncertainty.png": lambda p: plot_range_uncertainty(trajectories, p),
    }
    clock_path = workdir / artifacts.CLOCK_JSON
    plots.update(
        pattern_plots(
            trajectories,
            probe.fps,
            probe.n_frames[1],
            patterns or PatternParams(),
            NightClock.load(clock_path) if clock_path.exists() else NightClock(),
            read_json(workdir / artifacts.CALIBRATION_JSON).get("camera_height_m"),
            _save,
        )
    )
    names = []
    for filename, draw in plots.items():
        draw(report_dir / filename)
        names.append(f"{artifacts.REPORT_DIR}/{filename}")
    return names


def plot_counts(
    det1: Detections,
    det2: Detections,
    n_frames: dict[int, int],
    fps: float,
    sync: dict[str, Any],
    path: Path,
) -> None:
    """N(t) of both cameras on camera 1's clock (camera 2 shifted by the delay)."""
    delay = int(sync["delay_frames"])
    window = max(round(fps), 1)  # 1-s running sum: single frames are too spiky
    kernel = np.ones(window)
    n1 = np.convolve(det1.counts_per_frame(n_frames[1]), kernel, mode="same")
    n2 = np.convolve(det2.counts_per_frame(n_frames[2]), kernel, mode="same")
    fig, ax = plt.subplots(figsize=(10, 3.5))
    ax.plot(np.arange(len(n1)) / fps, n1, lw=0.8, label="camera 1")
    ax.plot((np.arange(len(n2)) - delay) / fps, n2, lw=0.8, alpha=0.8, label="camera 2")
    ax.set(
        xlabel="time on camera 1's clock (s)",
        ylabel="flashes per second",
        title=f"Flash counts aligned by delay {delay} frames "
        f"(confidence {float(sync['confidence']):.2f})",
    )
    ax.legend(loc="upper right")
    _save(fig, path)


def plot_delay(sync: dict[str, Any], fps: float, path: Path) -> None:
    """Histogram of the RANSAC windows' delays and the global cross-correlation."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.5))
    votes = np.asarray(sync.get("votes", []), dtype=float)
    if len(votes):
        # At least ±10 frames around the choice, so unanimous votes still read as a peak.
        lo = min(votes.min(), sync["delay_frames"] - 10)
        hi = max(votes.max(), sync["delay_frames"] + 10)
        left.hist(votes, bins=np.arange(lo - 0.5, hi + 1.5), color="tab:blue")
    left.axvline(sync["delay_frames"], color="tab:red", lw=1, label="chosen delay")
    left.set(xlabel="delay (frames)", ylabel="windows", title="Delay votes")
    left.legend()
    lags = np.asarray(sync.get("lags", []), dtype=float)
    correlation = np.asarray(sync.get("correlation", []), dtype=float)
    right.plot(lags / fps, correlation, lw=0.8)
    right.axvline(sync["delay_frames"] / fps, color="tab:red", lw=1)
    right.set(xlabel="delay (s)", ylabel="normalised correlation", title="N1 ⋆ N2")
    _save(fig, path)


def plot_residuals(fits: Mapping[str, Mapping[str, np.ndarray]], path: Path) -> None:
    """Residuals of each pose fit's pairs (degrees), inliers and outliers, one panel a fit.

    `fits` maps a panel title to the fit's ``residuals`` and ``inliers``; a fit without
    pairs (the refit where the first pose was kept) gets no panel.
    """
    drawn = {t: fit for t, fit in fits.items() if np.isfinite(fit["residuals"]).any()}
    panels = max(len(drawn), 1)
    fig, axes = plt.subplots(1, panels, figsize=(6 * panels, 3.5), squeeze=False)
    for ax, (title, fit) in zip(axes[0], drawn.items(), strict=False):
        residuals, inliers = np.asarray(fit["residuals"]), np.asarray(fit["inliers"], bool)
        finite = residuals[np.isfinite(residuals)]
        bins = np.linspace(0, np.quantile(finite, 0.99) * 1.05 + 1e-12, 50).tolist()
        ax.hist(residuals[inliers], bins=bins, label=f"inliers ({int(inliers.sum())})")
        ax.hist(
            residuals[~inliers], bins=bins, alpha=0.7, label=f"outliers ({int((~inliers).sum())})"
        )
        ax.legend()
        ax.set(xlabel="residual (degrees)", ylabel="pairs", title=title)
    if not drawn:
        axes[0, 0].set(title="no calibration pairs")
    fig.suptitle("Spatial calibration residuals")
    _save(fig, path)


def trajectory_segments(trajectories: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Line segments joining each trajectory's flash points in time order.

    Returns segments ``(n, 2, 3)`` (metres) and the trajectory id of each.
    """
    tid = np.asarray(trajectories["trajectory_id"], dtype=np.int64)
    order = np.lexsort((trajectories["frame"], tid))
    xyz = np.column_stack([trajectories[c] for c in ("x", "y", "z")])[order]
    same = tid[order][1:] == tid[order][:-1]
    return np.stack([xyz[:-1], xyz[1:]], axis=1)[same], tid[order][1:][same]


def plot_trajectories(trajectories: dict[str, np.ndarray], path: Path) -> None:
    """Trajectories in 3D and from above: each trajectory's flashes joined in time order
    by lines of its colour, flash points as dots."""
    fig = plt.figure(figsize=(11, 5))
    ax3d = fig.add_subplot(1, 2, 1, projection="3d")
    top = fig.add_subplot(1, 2, 2)
    x, y, z = trajectories["x"], trajectories["y"], trajectories["z"]
    colour = trajectories["trajectory_id"] % 20
    segments, owner = trajectory_segments(trajectories)
    colours = plt.get_cmap("tab20")(owner % 20)
    ax3d.add_collection3d(Line3DCollection(segments, colors=colours, linewidths=0.8))
    ax3d.scatter(x, y, z, c=colour, cmap="tab20", s=2, vmin=0, vmax=19)
    ax3d.scatter([0], [0], [0], c="k", marker="^", s=30)
    ax3d.set(xlabel="x (m)", ylabel="y (m)", zlabel="z (m)", title="Trajectories")
    top.add_collection(LineCollection(list(segments[:, :, :2]), colors=colours, linewidths=0.8))
    top.scatter(x, y, c=colour, cmap="tab20", s=2, vmin=0, vmax=19)
    top.plot([0], [0], "k^")
    top.set(xlabel="x (m)", ylabel="y (m)", title="From above (camera 1 at ▲)")
    top.set_aspect("equal", adjustable="datalim")
    _save(fig, path)


def plot_range_uncertainty(trajectories: dict[str, np.ndarray], path: Path) -> None:
    """Each point's range standard deviation, in percent of its range, against its range:
    how far out the reconstruction is sure of depth (it grows about as the range)."""
    fig, ax = plt.subplots(figsize=(6, 3.5))
    distance = np.asarray(trajectories["range_m"], dtype=np.float64)
    sd = np.asarray(trajectories.get("range_sd_m", np.full(len(distance), np.nan)))
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = 100.0 * sd / distance
    known = np.isfinite(relative)
    limit = 100.0 * SURE_RELATIVE_SD
    ax.scatter(distance[known], relative[known], s=2, alpha=0.5)
    ax.axhline(limit, color="k", linewidth=0.8, linestyle="--")
    sure = np.count_nonzero(sure_of_range(sd, distance))
    ax.set(
        xlabel="range from camera 1 (m)",
        ylabel="range σ (% of range)",
        title=f"Depth uncertainty: {sure} of {len(distance)} points within {limit:g} %",
    )
    _save(fig, path)


def _save(fig: plt.Figure, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
