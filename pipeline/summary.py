"""The summary of a run, built from what its units recorded.

One function for every reader: the report stage writes it to ``report/summary.json``
from the run folder's metrics files, and the service stores it on the job from the
stage rows' metrics (the same records), so the job page, the API and the report say
the same thing, also while a job is still running (missing values are None).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pipeline.artifacts import CAMERAS
from pipeline.graph import StageResult, Unit, position
from pipeline.params import ProcessParams


def summarise(records: Mapping[Unit, StageResult], params: ProcessParams) -> dict[str, Any]:
    """Counts, calibration quality, tracking statistics, warnings and timings of a run.

    Parameters
    ----------
    records : mapping of Unit to StageResult
        Metrics and warnings of the whole-run and per-camera units that have run
        (tracking chunks are summed up by their camera's merge unit).
    params : ProcessParams
        The run's parameters (copied into the summary).

    Returns
    -------
    dict
        ``counts``, ``delay_frames``, ``delay_confidence``, ``rotation``,
        ``translation``, ``residuals``, ``recording`` (the probe's frame size, rate,
        codecs and bits per pixel per camera), ``tracking`` (per camera), ``acceptance`` (per
        camera: candidates accepted and rejected by each kind of evidence), ``clock`` (when
        camera 1's frame 0 was recorded, UTC and local, and the sunset; `pipeline.clock`),
        ``patterns`` (the night's flash-pattern figures; `pipeline.patterns`), ``warnings``
        (every unit's, in pipeline order, but the first pose's once the refit replaced it),
        ``timings_s`` (per unit; ``track_cam<c>`` = the camera's tracking time summed
        over its chunks) and ``parameters``.
    """
    ordered = sorted(records.items(), key=lambda item: position(item[0]))
    metrics = {unit.slug: result.metrics for unit, result in ordered}

    def value(slug: str, key: str) -> Any:
        return metrics.get(slug, {}).get(key)

    def stage_metrics(slug: str) -> dict[str, Any] | None:
        """A whole-run stage's metrics without its timing (kept in ``timings_s``)."""
        if slug not in metrics:
            return None
        return {k: v for k, v in metrics[slug].items() if k != "seconds"}

    counts: dict[str, Any] = {}
    for camera in CAMERAS:
        counts[f"candidates_cam{camera}"] = value(f"merge_cam{camera}", "n_candidates")
        counts[f"refined_cam{camera}"] = value(f"merge_cam{camera}", "n_refined_positions")
        counts[f"flashes_cam{camera}"] = (value("accept", f"cam{camera}") or {}).get("accepted")
    counts.update(
        calibration_pairs=value("refit", "n_calibration_pairs"),
        calibration_inliers=value("refit", "n_calibration_inliers"),
        points=value("link", "n_points"),
        points_sure=value("triangulate", "n_points_sure"),
        streaks=value("link", "n_streaks"),
        trajectories=value("link", "n_trajectories"),
        ambiguous_links=value("link", "n_ambiguous_links"),
    )
    timings = {slug: m.get("seconds") for slug, m in metrics.items()}
    tracking = {}
    for camera in CAMERAS:
        stats = value(f"merge_cam{camera}", "tracking")
        if stats is not None:
            tracking[f"cam{camera}"] = stats
            timings[f"track_cam{camera}"] = stats.get("seconds")
    return {
        "counts": counts,
        "delay_frames": value("sync", "delay_frames"),
        "delay_confidence": value("sync", "delay_confidence"),
        "delay_set_aside": {
            f"cam{camera}": value("sync", f"frames_set_aside_cam{camera}") for camera in CAMERAS
        },
        "rotation": value("refit", "rotation"),
        "translation": value("refit", "translation"),
        "residuals": value("refit", "residuals") or {},
        "pose_refit": value("refit", "refit"),
        "tracking": tracking,
        "recording": stage_metrics("probe"),
        "acceptance": stage_metrics("accept"),
        "clock": stage_metrics("clock"),
        "patterns": value("patterns", "night"),
        "warnings": [
            w
            for unit, result in ordered
            if not (unit.slug == "pose" and value("refit", "refit"))
            for w in result.warnings
        ],
        "timings_s": timings,
        "parameters": params.model_dump(mode="json"),
    }
