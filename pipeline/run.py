"""The pipeline's stages as plain functions over a working directory.

Each stage reads its inputs from, and writes its outputs into, a local folder laid out
with the artifact names below; it returns a `StageResult` naming what it wrote. The CLI
runs the stages one after the other in the result folder (`process`); the service's
Celery tasks download a stage's inputs from object storage into a temporary folder,
call the same function and upload its outputs. Re-running a stage overwrites exactly
its own outputs, which is what makes re-runs and worker crashes safe.

Stage order: ``probe → track (chunks, per camera) → merge (per camera) → sync → pose →
triangulate → link → report``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache, partial
from pathlib import Path
from typing import Any, Self

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from pipeline.artifacts import (
    CALIBRATION_JSON,
    CALIBRATION_PAIRS_NPZ,
    CAMERAS,
    POINTS_NPZ,
    PROBE_JSON,
    SYNC_JSON,
    TRAJECTORIES_CSV,
    candidates_name,
    chunk_metrics_name,
    chunk_name,
    flashes_name,
    metrics_name,
)
from pipeline.classify import FlashClassifier
from pipeline.detections import Detections
from pipeline.flicker import FlickerParams, flickering
from pipeline.pose import PoseParams, calibration_pairs, estimate_pose
from pipeline.results import (
    Calibration,
    StereoProbe,
    load_points,
    read_calibration,
    read_json,
    save_points,
    write_calibration,
    write_json,
    write_trajectories,
)
from pipeline.sync import SyncParams, estimate_delay
from pipeline.tracking import TrackingParams, chunk_ranges, frames_read, track
from pipeline.trajectories import LinkingParams, link
from pipeline.triangulate import TriangulationParams, triangulate, validate_separation
from pipeline.video import check_stereo_pair, probe_video

STAGES = ("probe", "track", "merge", "sync", "pose", "triangulate", "link", "report")


class ClassifierParams(BaseModel):
    """Which flash classifier to run on candidate patches, and where to cut."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(True, description="Classify candidates; false = tracking only.")
    model: str | None = Field(None, description="ONNX model path; None = the shipped model.")
    card: str | None = Field(None, description="Model card JSON; None = beside the model.")
    threshold: float | None = Field(
        None, ge=0.0, le=1.0, description="Accept at probability >= this; None = the card's."
    )


class ProcessParams(BaseModel):
    """Every parameter of every stage; JSON-able, validated, immutable."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    tracking: TrackingParams = TrackingParams()
    classifier: ClassifierParams = ClassifierParams()
    sync: SyncParams = SyncParams()
    pose: PoseParams = PoseParams()
    triangulation: TriangulationParams = TriangulationParams()
    linking: LinkingParams = LinkingParams()
    flicker: FlickerParams = FlickerParams()
    chunk_s: float = Field(60.0, gt=0, description="Length of a tracking chunk, seconds.")

    def merged(self, overrides: Mapping[str, Any]) -> Self:
        """These parameters with ``overrides`` deep-merged in, validated.

        Raises
        ------
        pydantic.ValidationError
            If an override names an unknown parameter or has an invalid value.
        """
        return self.model_validate(_deep_merge(self.model_dump(), overrides))


def _deep_merge(base: dict[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), dict):
            merged[key] = _deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged


@dataclass
class StageResult:
    """What a stage wrote (names relative to the run folder) and what it measured."""

    outputs: list[str]
    metrics: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


Progress = Callable[[float], None]

# -- probe ---------------------------------------------------------------------------


def probe_stage(cam1: Sequence[Path], cam2: Sequence[Path], workdir: Path) -> StageResult:
    """Probe both cameras' chapter files and check they form a stereo pair.

    Raises
    ------
    pipeline.video.VideoError
        Naming the file, for unreadable, empty or non-equirectangular videos, chapters
        that disagree, or cameras with different fps or frame sizes.
    """
    started = time.perf_counter()
    info1, info2 = probe_video(cam1), probe_video(cam2)
    check_stereo_pair(info1, info2)
    probe = StereoProbe(
        width=info1.width,
        height=info1.height,
        fps=info1.fps,
        n_frames={1: info1.n_frames, 2: info2.n_frames},
        videos={1: info1, 2: info2},
    )
    probe.save(workdir)
    metrics = {
        "width": probe.width,
        "height": probe.height,
        "fps": probe.fps,
        "n_frames_cam1": info1.n_frames,
        "n_frames_cam2": info2.n_frames,
        "codec_cam1": info1.codec,
        "codec_cam2": info2.codec,
        "chapters_cam1": len(info1.chapters),
        "chapters_cam2": len(info2.chapters),
    }
    return _finish("probe", None, workdir, [PROBE_JSON], metrics, started)


def detections_probe_stage(
    det1: Detections, det2: Detections, width: int, height: int, fps: float, workdir: Path
) -> StageResult:
    """The probe of a run that starts from detections: sizes given, lengths inferred."""
    started = time.perf_counter()
    if width != 2 * height:
        raise ValueError(
            f"frames must be equirectangular (width = 2 × height), got {width}×{height}"
        )
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be a positive number, got {fps}")
    n_frames = {c: int(d.frame.max()) + 1 if len(d) else 0 for c, d in ((1, det1), (2, det2))}
    StereoProbe(width=width, height=height, fps=fps, n_frames=n_frames).save(workdir)
    metrics = {"width": width, "height": height, "fps": fps, **_per_camera("n_frames", n_frames)}
    return _finish("probe", None, workdir, [PROBE_JSON], metrics, started)


# -- tracking --------------------------------------------------------------------------


def plan_chunks(workdir: Path, params: ProcessParams) -> list[tuple[int, int, int]]:
    """Frame ranges to track independently: ``(camera, start, stop)`` for both cameras."""
    probe = StereoProbe.load(workdir)
    return [
        (camera, start, stop)
        for camera in CAMERAS
        for start, stop in chunk_ranges(
            probe.n_frames[camera], probe.fps, params.tracking, params.chunk_s
        )
    ]


def camera_chunks(workdir: Path, params: ProcessParams, camera: int) -> list[tuple[int, int]]:
    """The planned ``(start, stop)`` frame ranges of one camera."""
    return [(a, b) for c, a, b in plan_chunks(workdir, params) if c == camera]


def chapters_needed(
    workdir: Path, camera: int, start: int, stop: int, params: ProcessParams
) -> list[int]:
    """Indices of the chapter files that tracking frames ``[start, stop)`` decodes."""
    probe = StereoProbe.load(workdir)
    return list(
        probe.videos[camera].chapters_for(*frames_read(start, stop, probe.fps, params.tracking))
    )


@lru_cache(maxsize=4)
def _classifier(model: str | None, card: str | None) -> FlashClassifier:
    # One ONNX session per worker process, reused by every chunk it tracks.
    return FlashClassifier.load(model, card)


def load_classifier(params: ClassifierParams) -> FlashClassifier | None:
    return _classifier(params.model, params.card) if params.enabled else None


def track_chunk_stage(
    workdir: Path,
    camera: int,
    start: int,
    stop: int,
    videos: Mapping[int, Path],
    params: ProcessParams,
    progress: Progress | None = None,
) -> StageResult:
    """Track (and classify) every candidate flash of one camera in frames ``[start, stop)``.

    ``videos`` maps chapter index to a local file; it must hold at least the chapters
    `chapters_needed` names.
    """
    started = time.perf_counter()
    probe = StereoProbe.load(workdir)
    info = probe.videos[camera].with_paths(videos)
    done = 0

    def on_frames(n: int) -> None:
        nonlocal done
        done += n
        if progress is not None:
            progress(done / max(stop - start, 1))

    detections = track(
        info,
        start,
        stop,
        params.tracking,
        classifier=load_classifier(params.classifier),
        progress=on_frames,
    )
    out = workdir / chunk_name(camera, start, stop)
    out.parent.mkdir(parents=True, exist_ok=True)
    detections.to_npz(out)
    seconds = time.perf_counter() - started
    metrics = {
        "camera": camera,
        "start": start,
        "stop": stop,
        "n_candidates": len(detections),
        "seconds": seconds,
        "fps": (stop - start) / seconds if seconds > 0 else None,
    }
    write_json(workdir / chunk_metrics_name(camera, start, stop), metrics)
    return StageResult(
        outputs=[chunk_name(camera, start, stop), chunk_metrics_name(camera, start, stop)],
        metrics=metrics,
    )


def merge_stage(workdir: Path, camera: int, params: ProcessParams) -> StageResult:
    """Concatenate a camera's chunks and keep the candidates that are flashes.

    A candidate is accepted if the classifier accepts it (always, without one) and it
    does not sit on a flickering spot (`pipeline.flicker`). Writes every candidate
    (``candidates_cam<c>.npz``) and the accepted ones (``flashes_cam<c>.csv``).
    """
    started = time.perf_counter()
    ranges = camera_chunks(workdir, params, camera)
    missing = [
        chunk_name(camera, a, b)
        for a, b in ranges
        if not (workdir / chunk_name(camera, a, b)).exists()
    ]
    if missing:
        raise FileNotFoundError(f"camera {camera}: tracking chunks missing: {', '.join(missing)}")
    # Canonical row order (frame, row, column): results then do not depend on how a
    # tracker (ours, or another behind `reconstruct`) happened to list its blobs.
    candidates = Detections.concat(
        Detections.from_npz(workdir / chunk_name(camera, a, b)) for a, b in ranges
    ).sorted()
    threshold = accept_threshold(params.classifier)
    probe = StereoProbe.load(workdir)
    flicker = flickering(
        candidates.frame, candidates.x, candidates.y, probe.width, probe.fps, params.flicker
    )
    keep = ~flicker if threshold is None else ~flicker & (candidates.flash_probability >= threshold)
    accepted = candidates.select(keep)
    candidates.to_npz(workdir / candidates_name(camera))
    accepted.to_csv(workdir / flashes_name(camera))
    chunk_seconds = [
        read_json(workdir / chunk_metrics_name(camera, a, b)).get("seconds", 0.0)
        for a, b in ranges
        if (workdir / chunk_metrics_name(camera, a, b)).exists()
    ]
    metrics = {
        "camera": camera,
        "n_chunks": len(ranges),
        "n_candidates": len(candidates),
        "n_flickering": int(flicker.sum()),
        "n_accepted": len(accepted),
        "threshold": threshold,
        "tracking_seconds": float(sum(chunk_seconds)),
    }
    warnings = []
    if len(accepted) == 0:
        warnings.append(f"camera {camera}: no flashes accepted out of {len(candidates)} candidates")
    return _finish(
        "merge",
        camera,
        workdir,
        [candidates_name(camera), flashes_name(camera)],
        metrics,
        started,
        warnings,
    )


def accept_threshold(params: ClassifierParams) -> float | None:
    """Probability at or above which a candidate is a flash; None = accept all."""
    if not params.enabled:
        return None
    if params.threshold is not None:
        return params.threshold
    return _classifier(params.model, params.card).threshold


# -- calibration, triangulation, linking ------------------------------------------------


def _accepted(workdir: Path) -> tuple[Detections, Detections]:
    return (
        Detections.from_csv(workdir / flashes_name(1)),
        Detections.from_csv(workdir / flashes_name(2)),
    )


def sync_stage(workdir: Path, params: ProcessParams) -> StageResult:
    """Frame delay between the cameras from their per-frame flash counts."""
    started = time.perf_counter()
    probe = StereoProbe.load(workdir)
    det1, det2 = _accepted(workdir)
    estimate = estimate_delay(
        det1.counts_per_frame(probe.n_frames[1]),
        det2.counts_per_frame(probe.n_frames[2]),
        probe.fps,
        params.sync,
    )
    write_json(workdir / SYNC_JSON, estimate.to_dict())
    metrics = {
        "delay_frames": estimate.delay_frames,
        "delay_s": estimate.delay_frames / probe.fps,
        "delay_confidence": estimate.confidence,
        "n_windows": estimate.n_windows,
    }
    return _finish("sync", None, workdir, [SYNC_JSON], metrics, started, list(estimate.warnings))


def pose_stage(
    workdir: Path,
    params: ProcessParams,
    separation_m: float,
    camera_height_m: float | None = None,
) -> StageResult:
    """Relative pose from frames where each camera sees exactly one flash.

    Writes ``calibration.json`` (the delay from ``sync.json`` included); the camera
    height, when known, is recorded there as metadata.
    """
    started = time.perf_counter()
    validate_separation(separation_m)
    probe = StereoProbe.load(workdir)
    sync = read_json(workdir / SYNC_JSON)
    det1, det2 = _accepted(workdir)
    pairs = calibration_pairs(det1, det2, int(sync["delay_frames"]), probe.width)
    estimate = estimate_pose(pairs, params.pose)
    np.savez_compressed(
        workdir / CALIBRATION_PAIRS_NPZ,
        frame1=pairs.frame1,
        residuals=estimate.residuals,
        inliers=estimate.inliers,
    )
    calibration = Calibration(
        delay_frames=int(sync["delay_frames"]),
        delay_confidence=float(sync["confidence"]),
        pose=estimate.pose,
        separation_m=separation_m,
        fps=probe.fps,
        width=probe.width,
        height=probe.height,
    )
    warnings = [*sync.get("warnings", []), *estimate.warnings]
    write_calibration(
        workdir / CALIBRATION_JSON,
        calibration,
        extra={
            "n_calibration_pairs": estimate.n_pairs,
            "n_calibration_inliers": estimate.n_inliers,
            "residuals": estimate.stats,
            "camera_height_m": camera_height_m,
            "warnings": warnings,
        },
    )
    metrics = {
        "n_calibration_pairs": estimate.n_pairs,
        "n_calibration_inliers": estimate.n_inliers,
        **{f"residual_{k}": v for k, v in estimate.stats.items()},
    }
    return _finish(
        "pose",
        None,
        workdir,
        [CALIBRATION_JSON, CALIBRATION_PAIRS_NPZ],
        metrics,
        started,
        list(estimate.warnings),
    )


def triangulate_stage(workdir: Path, params: ProcessParams, separation_m: float) -> StageResult:
    """Match flashes between synchronised frames and triangulate them in metres."""
    started = time.perf_counter()
    validate_separation(separation_m)
    calibration = read_calibration(workdir / CALIBRATION_JSON)
    det1, det2 = _accepted(workdir)
    points = triangulate(
        det1,
        det2,
        calibration.delay_frames,
        calibration.pose,
        calibration.width,
        separation_m,
        params.triangulation,
    )
    save_points(workdir / POINTS_NPZ, points)
    metrics = {
        "n_points": len(points),
        "median_gap_m": float(np.median(points.gap_m)) if len(points) else None,
        "median_range_m": float(np.median(points.range_m)) if len(points) else None,
    }
    warnings = [] if len(points) else ["no flash could be triangulated"]
    return _finish("triangulate", None, workdir, [POINTS_NPZ], metrics, started, warnings)


def link_stage(workdir: Path, params: ProcessParams) -> StageResult:
    """Link triangulated flashes into streaks and trajectories; write trajectories.csv."""
    started = time.perf_counter()
    probe = StereoProbe.load(workdir)
    points = load_points(workdir / POINTS_NPZ)
    linking = link(points, probe.fps, params.linking)
    write_trajectories(workdir / TRAJECTORIES_CSV, points, linking, probe.fps)
    metrics = {
        "n_points": len(points),
        "n_streaks": len(np.unique(linking.streak_id)),
        "n_trajectories": len(np.unique(linking.trajectory_id)),
    }
    return _finish("link", None, workdir, [TRAJECTORIES_CSV], metrics, started)


def report_stage(workdir: Path, params: ProcessParams) -> StageResult:
    """Plots and ``summary.json`` of a finished run."""
    from pipeline.report import write_report  # matplotlib is only needed here

    started = time.perf_counter()
    outputs = write_report(workdir, params)
    return _finish("report", None, workdir, outputs, {"n_plots": len(outputs) - 1}, started)


def stage_inputs(
    stage: str, workdir: Path, params: ProcessParams, camera: int | None = None
) -> list[str]:
    """Artifact names a stage other than ``track`` reads from the run folder.

    ``merge`` needs ``probe.json`` present first: its chunk list comes from it.
    """
    accepted = [flashes_name(1), flashes_name(2)]
    match stage:
        case "merge":
            if camera is None:
                raise ValueError("the merge stage works per camera")
            ranges = camera_chunks(workdir, params, camera)
            return [PROBE_JSON] + [
                name
                for a, b in ranges
                for name in (chunk_name(camera, a, b), chunk_metrics_name(camera, a, b))
            ]
        case "sync":
            return [PROBE_JSON, *accepted]
        case "pose":
            return [PROBE_JSON, SYNC_JSON, *accepted]
        case "triangulate":
            return [CALIBRATION_JSON, *accepted]
        case "link":
            return [PROBE_JSON, POINTS_NPZ]
        case "report":
            return [
                PROBE_JSON,
                SYNC_JSON,
                CALIBRATION_JSON,
                CALIBRATION_PAIRS_NPZ,
                POINTS_NPZ,
                TRAJECTORIES_CSV,
                *accepted,
                *(metrics_name(s) for s in ("probe", "sync", "pose", "triangulate", "link")),
                *(metrics_name("merge", c) for c in CAMERAS),
            ]
    raise ValueError(f"unknown stage {stage!r}; stages are {', '.join(STAGES)}")


def _finish(
    stage: str,
    camera: int | None,
    workdir: Path,
    outputs: list[str],
    metrics: dict[str, Any],
    started: float,
    warnings: list[str] | None = None,
) -> StageResult:
    """Record a stage's metrics beside its outputs (the report reads them)."""
    metrics = {**metrics, "seconds": time.perf_counter() - started}
    warnings = warnings or []
    name = metrics_name(stage, camera)
    write_json(workdir / name, {"metrics": metrics, "warnings": warnings})
    return StageResult(outputs=[*outputs, name], metrics=metrics, warnings=warnings)


def _per_camera(key: str, values: Mapping[int, Any]) -> dict[str, Any]:
    return {f"{key}_cam{c}": v for c, v in values.items()}


# -- in-process runs (the CLI) -----------------------------------------------------------

#: Called with a stage label (e.g. "track cam1") and the fraction of it done.
RunProgress = Callable[[str, float], None]


@dataclass
class RunOutcome:
    """Every stage's result of an in-process run, in the order they ran."""

    out_dir: Path
    results: dict[str, StageResult] = field(default_factory=dict)

    @property
    def warnings(self) -> list[str]:
        return [w for r in self.results.values() for w in r.warnings]


def process(
    cam1: Sequence[Path],
    cam2: Sequence[Path],
    separation_m: float,
    out_dir: Path,
    params: ProcessParams | None = None,
    progress: RunProgress | None = None,
    camera_height_m: float | None = None,
) -> RunOutcome:
    """Run every stage on two cameras' chapter files, in this process.

    Parameters
    ----------
    cam1, cam2 : sequence of Path
        Each camera's chapter files, in recording order.
    separation_m : float
        Measured distance between the two cameras, metres.
    out_dir : Path
        Result folder (CONTRACT files at its top, intermediates under ``work/``).
    params : ProcessParams, optional
        Parameters of every stage; defaults otherwise.
    progress : callable, optional
        ``progress(stage_label, fraction)``.
    camera_height_m : float, optional
        Height of the cameras above the ground, metres (metadata).
    """
    params = params or ProcessParams()
    validate_separation(separation_m)
    report = progress or (lambda label, fraction: None)
    outcome = RunOutcome(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    outcome.results["probe"] = probe_stage(cam1, cam2, out_dir)
    report("probe", 1.0)
    for camera, videos in ((1, cam1), (2, cam2)):
        ranges = camera_chunks(out_dir, params, camera)
        fraction = _range_progress(report, f"track cam{camera}", ranges)
        for start, stop in ranges:
            outcome.results[f"track_cam{camera}_{start}"] = track_chunk_stage(
                out_dir,
                camera,
                start,
                stop,
                dict(enumerate(videos)),
                params,
                progress=partial(fraction, start, stop),
            )
        outcome.results[f"merge_cam{camera}"] = merge_stage(out_dir, camera, params)
    return _finish_run(outcome, separation_m, params, report, camera_height_m)


def _range_progress(
    report: RunProgress, label: str, ranges: list[tuple[int, int]]
) -> Callable[[int, int, float], None]:
    """Turn "fraction f of chunk [a, b) done" into the fraction of all ``ranges`` done."""
    total = max(sum(b - a for a, b in ranges), 1)
    before = {a: sum(d - c for c, d in ranges if c < a) for a, _ in ranges}
    return lambda a, b, f: report(label, (before[a] + f * (b - a)) / total)


def reconstruct(
    flashes1: Path,
    flashes2: Path,
    width: int,
    height: int,
    fps: float,
    separation_m: float,
    out_dir: Path,
    params: ProcessParams | None = None,
    progress: RunProgress | None = None,
) -> RunOutcome:
    """Run stages 4–8 from per-camera detections (``frame,x,y`` CSVs) in this process.

    The detections are taken as accepted flashes; they are copied, normalised, to
    ``flashes_cam1.csv`` / ``flashes_cam2.csv`` in ``out_dir``.
    """
    params = params or ProcessParams()
    validate_separation(separation_m)
    report = progress or (lambda label, fraction: None)
    out_dir.mkdir(parents=True, exist_ok=True)
    det1, det2 = Detections.from_csv(flashes1), Detections.from_csv(flashes2)
    for camera, det in ((1, det1), (2, det2)):
        det.sorted().to_csv(out_dir / flashes_name(camera))
    outcome = RunOutcome(out_dir)
    outcome.results["probe"] = detections_probe_stage(det1, det2, width, height, fps, out_dir)
    return _finish_run(outcome, separation_m, params, report)


def _finish_run(
    outcome: RunOutcome,
    separation_m: float,
    params: ProcessParams,
    report: RunProgress,
    camera_height_m: float | None = None,
) -> RunOutcome:
    out_dir = outcome.out_dir
    steps: list[tuple[str, Callable[[], StageResult]]] = [
        ("sync", lambda: sync_stage(out_dir, params)),
        ("pose", lambda: pose_stage(out_dir, params, separation_m, camera_height_m)),
        ("triangulate", lambda: triangulate_stage(out_dir, params, separation_m)),
        ("link", lambda: link_stage(out_dir, params)),
        ("report", lambda: report_stage(out_dir, params)),
    ]
    for name, step in steps:
        report(name, 0.0)
        outcome.results[name] = step()
        report(name, 1.0)
    return outcome
