"""Report plots of the night's flash pattern, for people who study fireflies.

* ``flash_durations.png``: histogram of flash durations (one-frame bins), median marked;
* ``interflash_intervals.png``: histogram of inter-flash intervals within trains
  (one-frame bins), median and histogram peak marked;
* ``flashes_per_minute.png``: flash onsets per minute through the night, against clock
  time (local when the time zone is known, else UTC) when the night's clock is known,
  else against minutes since the recording started; the sunset marked when in range;
* ``height_profile.png``: flash points per height band above the ground (z + camera
  height), or relative to camera 1 when the camera height is unknown.

Per-flash values are recomputed from ``trajectories.csv`` with the patterns stage's own
functions and parameters, so the plots show exactly what ``flash_patterns.csv`` and
the summary report.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.dates as mdates
import matplotlib.pyplot as plt
import numpy as np

from pipeline.clock import NightClock
from pipeline.params import PatternParams
from pipeline.patterns import flashes_from_streaks, histogram_mode, intervals

Draw = Callable[[Path], None]


def pattern_plots(
    trajectories: dict[str, np.ndarray],
    fps: float,
    n_frames: int,
    params: PatternParams,
    clock: NightClock,
    camera_height_m: float | None,
    save: Callable[[plt.Figure, Path], None],
) -> dict[str, Draw]:
    """The flash-pattern plots by file name, each a function of its path."""
    flashes = flashes_from_streaks(
        trajectories["trajectory_id"],
        trajectories["streak_id"],
        trajectories["frame"],
        params.join_gap_frames,
        n_frames,
    )
    durations = flashes.n_frames[~flashes.censored] / fps
    ifi_s, _ = intervals(flashes, fps, params.train_gap_s)

    def durations_plot(path: Path) -> None:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        _frame_histogram(ax, durations, fps, "tab:orange")
        if len(durations):
            ax.axvline(np.median(durations), color="k", lw=1, label="median")
            ax.legend()
        ax.set(
            xlabel="flash duration (s)",
            ylabel="flashes",
            title=f"Flash duration ({len(durations)} flashes)",
        )
        save(fig, path)

    def intervals_plot(path: Path) -> None:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        _frame_histogram(ax, ifi_s, fps, "tab:green")
        if len(ifi_s):
            ax.axvline(np.median(ifi_s), color="k", lw=1, label="median")
            mode = histogram_mode(ifi_s, fps) or 0.0
            ax.axvline(mode, color="tab:red", lw=1, ls="--", label=f"peak {mode:.2f} s")
            ax.legend()
        ax.set(
            xlabel="inter-flash interval, onset to onset within a train (s)",
            ylabel="intervals",
            title=f"Inter-flash interval ({len(ifi_s)} intervals)",
        )
        save(fig, path)

    def per_minute_plot(path: Path) -> None:
        fig, ax = plt.subplots(figsize=(10, 3.5))
        duration_s = n_frames / fps
        # One-minute bins, finer for short recordings (at least ~20 bins), still per minute.
        bin_s = 60.0 if duration_s >= 1200 else max(duration_s / 20, 1.0 / fps)
        edges = np.arange(0.0, duration_s + bin_s, bin_s)
        counts, _ = np.histogram(flashes.first_frame / fps, bins=edges)
        rate = counts * 60.0 / bin_s
        if clock.start_utc is not None:
            start = clock.local(clock.start_utc)
            times = [start + dt.timedelta(seconds=float(s)) for s in edges[:-1]]
            ax.step(mdates.date2num(times), rate, where="post", color="tab:blue")
            shown = "%H:%M" if duration_s >= 1200 else "%H:%M:%S"
            ax.xaxis.set_major_formatter(mdates.DateFormatter(shown, tz=start.tzinfo))
            zone = clock.time_zone or "UTC"
            ax.set_xlabel(f"clock time ({zone}), night of {start:%Y-%m-%d}")
            if clock.sunset_utc is not None:
                sunset = clock.local(clock.sunset_utc)
                if times[0] <= sunset <= times[-1] + dt.timedelta(seconds=bin_s):
                    ax.axvline(mdates.date2num(sunset), color="tab:red", lw=1, label="sunset")
                    ax.legend()
        else:
            ax.step(edges[:-1] / 60.0, rate, where="post", color="tab:blue")
            ax.set_xlabel("minutes since the recording started (clock time unknown)")
        ax.set(ylabel="flashes per minute", title="Flashes through the night")
        save(fig, path)

    def height_plot(path: Path) -> None:
        fig, ax = plt.subplots(figsize=(5, 5))
        z = np.asarray(trajectories["z"], dtype=np.float64)
        if camera_height_m is not None:
            height, label = z + camera_height_m, "height above the ground (m)"
        else:
            height, label = z, "height relative to camera 1 (m; camera height unknown)"
        if len(height):
            edges = np.arange(np.floor(height.min() * 4) / 4, height.max() + 0.25, 0.25)
            ax.hist(height, bins=edges.tolist(), orientation="horizontal", color="tab:olive")
        if camera_height_m is not None:
            ax.axhline(0, color="k", lw=1)
            ax.axhline(camera_height_m, color="tab:gray", lw=1, ls="--", label="cameras")
            ax.legend()
        ax.set(xlabel="flash points", ylabel=label, title="Height profile")
        save(fig, path)

    return {
        "flash_durations.png": durations_plot,
        "interflash_intervals.png": intervals_plot,
        "flashes_per_minute.png": per_minute_plot,
        "height_profile.png": height_plot,
    }


def _frame_histogram(ax: plt.Axes, values_s: np.ndarray, fps: float, colour: str) -> None:
    """Histogram in one-frame bins centred on whole frames (durations are frame counts)."""
    if len(values_s) == 0:
        ax.text(0.5, 0.5, "none", transform=ax.transAxes, ha="center")
        return
    frames = np.round(values_s * fps)
    edges = (np.arange(frames.min(), frames.max() + 2) - 0.5) / fps
    ax.hist(values_s, bins=edges.tolist(), color=colour)
