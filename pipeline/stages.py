"""The stage functions of the graph (`pipeline.graph.STAGES`): files in, science, files out.

Each function takes a `StageContext` (its unit, the run's parameters and inputs, the
run folder) and returns what it measured; it reads the files its graph entry declares
and writes the ones it declares, under names that are deterministic per unit, so that
re-running a unit overwrites exactly its own outputs. The science lives in the modules
these call; nothing here knows whether it runs in the CLI or in a Celery worker.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pipeline.acceptance import Evidence, assess, confirm, refined, stereo_gates
from pipeline.artifacts import (
    ACCEPTANCE_NPZ,
    CALIBRATION_JSON,
    CALIBRATION_PAIRS_NPZ,
    CAMERAS,
    CANDIDATES_NPZ,
    CHUNK_METRICS_JSON,
    CHUNK_NPZ,
    CLOCK_JSON,
    EVIDENCE_NPZ,
    FAINT_CHUNK_NPZ,
    FLASH_PATTERNS_CSV,
    FLASHES_CSV,
    POINTS_NPZ,
    POSE_JSON,
    REFIT_PAIRS_NPZ,
    SUMMARY_JSON,
    SYNC_JSON,
    TRAJECTORIES_CSV,
)
from pipeline.classify import FlashClassifier
from pipeline.clock import NightClock, night_clock
from pipeline.detections import Detections
from pipeline.evidence_features import stereo_matches
from pipeline.evidence_model import acceptance_counts, evidence_model, weigh
from pipeline.geometry import angle_between, rotation_angle
from pipeline.graph import StageContext, StageResult, earlier_units, read_record
from pipeline.jsonio import read_json, write_json
from pipeline.params import AcceptanceParams, ClassifierParams, validate_separation
from pipeline.pose import (
    PoseError,
    PoseEstimate,
    baseline_warnings,
    calibrate_pose,
    estimate_pose,
    fit_warnings,
    median_residual_px,
    worst_axis_covariance,
)
from pipeline.pose_refit import jackknife_scaled, stereo_match_pairs
from pipeline.probe import LOW_BITS_PER_PIXEL, StereoProbe
from pipeline.results import (
    Calibration,
    load_points,
    read_calibration,
    save_points,
    write_calibration,
    write_trajectories,
)
from pipeline.summary import summarise
from pipeline.sync import estimate_delay
from pipeline.tracking import TrackingStats, track_with_stats
from pipeline.trajectories import link as link_points
from pipeline.triangulate import sure_of_range
from pipeline.triangulate import triangulate as triangulate_points
from pipeline.video import check_stereo_pair, probe_video


def _chapters(videos: Mapping[int, Path]) -> list[Path]:
    return [videos[i] for i in sorted(videos)]


def probe(ctx: StageContext) -> StageResult:
    """Probe both cameras' chapter files and check they form a stereo pair.

    Raises
    ------
    pipeline.probe.VideoError
        Naming the file, for unreadable, empty or non-equirectangular videos, chapters
        that disagree, or cameras with different fps or frame sizes.
    """
    info1, info2 = (probe_video(_chapters(ctx.videos[camera])) for camera in CAMERAS)
    check_stereo_pair(info1, info2)
    StereoProbe(
        width=info1.width,
        height=info1.height,
        fps=info1.fps,
        n_frames={1: info1.n_frames, 2: info2.n_frames},
        videos={1: info1, 2: info2},
    ).save(ctx.workdir)
    return StageResult(
        metrics={
            "width": info1.width,
            "height": info1.height,
            "fps": info1.fps,
            "n_frames_cam1": info1.n_frames,
            "n_frames_cam2": info2.n_frames,
            "codec_cam1": info1.codec,
            "codec_cam2": info2.codec,
            "chapters_cam1": len(info1.chapters),
            "chapters_cam2": len(info2.chapters),
            "bits_per_pixel_cam1": info1.bits_per_pixel,
            "bits_per_pixel_cam2": info2.bits_per_pixel,
        },
        warnings=[
            f"camera {camera}: encoded at {bpp:.3f} bit per pixel and frame, under "
            f"{LOW_BITS_PER_PIXEL}: compression erases faint flashes (record at the "
            "camera's highest bitrate, and upload the camera's own files)"
            for camera, bpp in ((1, info1.bits_per_pixel), (2, info2.bits_per_pixel))
            if bpp is not None and bpp < LOW_BITS_PER_PIXEL
        ],
    )


def probe_detections(
    det1: Detections, det2: Detections, width: int, height: int, fps: float, workdir: Path
) -> StageResult:
    """The probe of a run that starts from detections: sizes given, lengths inferred."""
    if width != 2 * height:
        raise ValueError(
            f"frames must be equirectangular (width = 2 × height), got {width}×{height}"
        )
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be a positive number, got {fps}")
    n_frames = {c: int(d.frame.max()) + 1 if len(d) else 0 for c, d in ((1, det1), (2, det2))}
    StereoProbe(width=width, height=height, fps=fps, n_frames=n_frames).save(workdir)
    metrics = {"width": width, "height": height, "fps": fps}
    metrics.update({f"n_frames_cam{c}": n for c, n in n_frames.items()})
    return StageResult(metrics=metrics)


@lru_cache(maxsize=4)
def _classifier(model: str | None, card: str | None) -> FlashClassifier:
    # One ONNX session per process, reused by every chunk it tracks.
    return FlashClassifier.load(model, card)


def load_classifier(params: ClassifierParams) -> FlashClassifier | None:
    """The classifier the parameters name, or None when classification is off."""
    return _classifier(params.model, params.card) if params.enabled else None


def accept_threshold(params: ClassifierParams) -> float | None:
    """Probability at or above which a candidate is a flash; None = accept all."""
    if not params.enabled:
        return None
    if params.threshold is not None:
        return params.threshold
    return _classifier(params.model, params.card).threshold


def track(ctx: StageContext) -> StageResult:
    """Track (and classify) every candidate flash of one camera in one frame range."""
    camera, start, stop = ctx.unit.camera, ctx.unit.start, ctx.unit.stop
    assert camera is not None and start is not None and stop is not None
    info = ctx.probe.videos[camera].with_paths(ctx.videos[camera])
    done = 0

    def on_frames(n: int) -> None:
        nonlocal done
        done += n
        ctx.progress(done / max(stop - start, 1))

    result = track_with_stats(
        info,
        start,
        stop,
        ctx.params.tracking,
        classifier=load_classifier(ctx.params.classifier),
        progress=on_frames,
    )
    out = ctx.path(CHUNK_NPZ)
    out.parent.mkdir(parents=True, exist_ok=True)
    result.detections.to_npz(out)
    faint = ctx.path(FAINT_CHUNK_NPZ)
    faint.parent.mkdir(parents=True, exist_ok=True)
    result.faint_peaks.to_npz(faint, spots_only=True)
    metrics = {
        "camera": camera,
        "start": start,
        "stop": stop,
        **asdict(result.stats),
        "key_frames": result.key_frames.tolist(),
    }
    return StageResult(metrics=metrics)


def _tracking_totals(chunk_metrics: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """A camera's `TrackingStats` and tracking time summed over its chunks."""
    chunk_metrics = list(chunk_metrics)
    totals: dict[str, Any] = {
        name: int(sum(m.get(name, 0) for m in chunk_metrics))
        for name in TrackingStats.__dataclass_fields__
    }
    seconds = float(sum(m.get("seconds", 0.0) for m in chunk_metrics))
    totals["seconds"] = seconds
    totals["fps"] = totals["frames"] / seconds if seconds > 0 else None
    return totals


def _key_frames(chunk_metrics: Iterable[Mapping[str, Any]]) -> NDArray[np.int64] | None:
    """The key frames of a camera's chunks, ascending; None if a chunk did not record
    them (tracked by an earlier release)."""
    parts = [m.get("key_frames") for m in chunk_metrics]
    if not parts or any(part is None for part in parts):
        return None
    return np.unique(np.concatenate([np.asarray(p, np.int64) for p in parts]))


def merge(ctx: StageContext) -> StageResult:
    """Concatenate a camera's chunks and weigh each candidate's own evidence.

    Writes every candidate (``candidates_cam<c>.npz``, positions refined along the light
    curve: `pipeline.acceptance.refined`) and its step-1 evidence
    (``evidence_cam<c>.npz``: flicker, light curve, classifier, SNR;
    `pipeline.acceptance.assess`, which also counts the chunks' faint peaks as lit).
    """
    camera = ctx.unit.camera
    chunks, faint_chunks = ctx.paths(CHUNK_NPZ), ctx.paths(FAINT_CHUNK_NPZ)
    missing = [
        p.relative_to(ctx.workdir).as_posix() for p in (*chunks, *faint_chunks) if not p.exists()
    ]
    if missing:
        raise FileNotFoundError(f"camera {camera}: tracking chunks missing: {', '.join(missing)}")
    # Canonical row order (frame, row, column): results then do not depend on how a
    # tracker (ours, or another behind `reconstruct`) happened to list its blobs.
    measured = Detections.concat(Detections.from_npz(p) for p in chunks).sorted()
    candidates = refined(measured, ctx.probe.width, ctx.probe.fps, ctx.params.acceptance)
    n_refined = int(np.count_nonzero((candidates.x != measured.x) | (candidates.y != measured.y)))
    candidates = candidates.sorted()
    threshold = accept_threshold(ctx.params.classifier)
    faint = Detections.concat(Detections.from_npz(p) for p in faint_chunks)
    evidence = assess(
        candidates,
        ctx.probe.width,
        ctx.probe.fps,
        threshold,
        ctx.params.acceptance,
        ctx.params.flicker,
        faint,
    )
    chunk_metrics = [read_json(p)["metrics"] for p in ctx.paths(CHUNK_METRICS_JSON) if p.exists()]
    evidence = replace(evidence, key_frames=_key_frames(chunk_metrics))
    candidates.to_npz(ctx.path(CANDIDATES_NPZ))
    evidence.save(ctx.path(EVIDENCE_NPZ))
    tracking = _tracking_totals(chunk_metrics)
    metrics = {
        "camera": camera,
        "n_chunks": len(chunks),
        "n_candidates": len(candidates),
        "n_faint_peaks": len(faint),
        "n_refined_positions": n_refined,
        "verdicts": evidence.counts(),
        "threshold": threshold,
        "tracking": tracking,
    }
    warnings = []
    if not evidence.confident.any():
        warnings.append(
            f"camera {camera}: no confident flash among {len(candidates)} candidates (if the "
            "recording shows fireflies, lower tracking.threshold or classifier.threshold)"
        )
    return StageResult(metrics=metrics, warnings=warnings)


def import_detections(
    detections: Mapping[int, Detections], workdir: Path, width: int, params: AcceptanceParams
) -> None:
    """Write detections made elsewhere as a run's candidates and evidence (`reconstruct`).

    They are taken as flashes, except rows whose SNR is below ``params.confident_snr``
    (`pipeline.acceptance.Evidence.imported`), which need stereo confirmation. Their
    positions are kept as given: our own flashes were refined along the light curve
    before they were written, and refining twice would smooth them twice.
    """
    for camera, found in detections.items():
        ordered = found.sorted()
        path = workdir / CANDIDATES_NPZ.format(camera=camera)
        path.parent.mkdir(parents=True, exist_ok=True)
        ordered.to_npz(path)
        evidence = Evidence.imported(ordered, width, params)
        evidence.save(workdir / EVIDENCE_NPZ.format(camera=camera))


def _candidates(
    ctx: StageContext,
) -> tuple[tuple[Detections, Detections], tuple[Evidence, Evidence]]:
    det1, det2 = (Detections.from_npz(p) for p in ctx.paths(CANDIDATES_NPZ))
    ev1, ev2 = (Evidence.load(p) for p in ctx.paths(EVIDENCE_NPZ))
    return (det1, det2), (ev1, ev2)


def _confident(ctx: StageContext) -> tuple[Detections, Detections]:
    (det1, det2), (ev1, ev2) = _candidates(ctx)
    return det1.select(ev1.confident), det2.select(ev2.confident)


def _accepted(ctx: StageContext) -> tuple[Detections, Detections]:
    det1, det2 = (Detections.from_csv(p) for p in ctx.paths(FLASHES_CSV))
    return det1, det2


def sync(ctx: StageContext) -> StageResult:
    """Frame delay between the cameras from their per-frame flash counts."""
    probe = ctx.probe
    (det1, det2), (ev1, ev2) = _candidates(ctx)
    confident1, confident2 = det1.select(ev1.confident), det2.select(ev2.confident)
    estimate = estimate_delay(
        confident1.counts_per_frame(probe.n_frames[1]),
        confident2.counts_per_frame(probe.n_frames[2]),
        probe.fps,
        ctx.params.sync,
        key_frames=(ev1.key_frames, ev2.key_frames),
    )
    write_json(ctx.path(SYNC_JSON), estimate.to_dict())
    metrics = {
        "delay_frames": estimate.delay_frames,
        "delay_s": estimate.delay_frames / probe.fps,
        "delay_confidence": estimate.confidence,
        "n_windows": estimate.n_windows,
        "n_flashes_cam1": len(confident1),
        "n_flashes_cam2": len(confident2),
        "frames_set_aside_cam1": estimate.set_aside[0],
        "frames_set_aside_cam2": estimate.set_aside[1],
    }
    return StageResult(metrics=metrics, warnings=list(estimate.warnings))


def pose(ctx: StageContext) -> StageResult:
    """Relative pose from frames where each camera sees exactly one flash (or one begin).

    Writes the first pose, in ``calibration.json``'s layout, to ``work/pose.json`` (the
    delay from ``sync.json`` included; the camera height, when known, as metadata):
    acceptance matches the cameras with it, and `refit` fits the final one.
    """
    validate_separation(ctx.separation_m)
    probe = ctx.probe
    delay = read_json(ctx.path(SYNC_JSON))
    det1, det2 = _confident(ctx)
    fit = calibrate_pose(det1, det2, int(delay["delay_frames"]), probe.width, ctx.params.pose)
    estimate, warnings = fit.estimate, fit.warnings
    save_pairs(ctx.path(CALIBRATION_PAIRS_NPZ), fit.pairs.frame1, estimate)
    calibration = Calibration(
        delay_frames=int(delay["delay_frames"]),
        delay_confidence=float(delay["confidence"]),
        pose=estimate.pose,
        separation_m=ctx.separation_m,
        fps=probe.fps,
        width=probe.width,
        height=probe.height,
        covariance=estimate.covariance,
    )
    write_calibration(
        ctx.path(POSE_JSON),
        calibration,
        extra={
            "n_calibration_pairs": estimate.n_pairs,
            "n_calibration_inliers": estimate.n_inliers,
            "residuals": estimate.stats,
            "calibration_min_snr": fit.min_snr,
            "pose_fits": fit.tried,
            "camera_height_m": ctx.camera_height_m,
            "warnings": [*delay.get("warnings", []), *warnings],
        },
    )
    metrics = {
        "n_calibration_pairs": estimate.n_pairs,
        "n_calibration_inliers": estimate.n_inliers,
        "rotation": estimate.pose.rotation.tolist(),
        "translation": estimate.pose.translation.tolist(),
        "residuals": estimate.stats,
        "calibration_min_snr": fit.min_snr,
    }
    return StageResult(metrics=metrics, warnings=warnings)


def accept(ctx: StageContext) -> StageResult:
    """Decide which candidates are flashes, once the delay and the pose are known.

    The evidence model (`pipeline.evidence_model`) weighs every kind of evidence on
    each candidate, the other camera's included; without one (or with another patch
    classifier than its own) the rules accept the confident candidates and the doubtful
    ones the other camera confirms (`pipeline.acceptance.confirm`). Writes
    ``flashes_cam1.csv`` and ``flashes_cam2.csv`` and each candidate's decision
    (``acceptance_cam*.npz``); the metrics count, per camera, the candidates accepted
    and rejected by each kind of evidence.
    """
    validate_separation(ctx.separation_m)
    calibration = read_calibration(ctx.path(POSE_JSON))
    candidates, evidence = _candidates(ctx)
    params = ctx.params.acceptance
    model, note = evidence_model(params, ctx.params.classifier, ctx.params.tracking)
    gates = stereo_gates(params, ctx.params.triangulation)
    if model is not None:
        matches = stereo_matches(
            candidates,
            calibration.delay_frames,
            calibration.pose,
            calibration.width,
            ctx.separation_m,
            gates,
        )
        weighed = weigh(
            model,
            candidates,
            evidence,
            matches,
            calibration.width,
            calibration.fps,
            ctx.params.flicker,
            params.evidence_threshold,
        )
        accepted = (weighed.accepted1, weighed.accepted2)
        matched = (weighed.matched1, weighed.matched2)
        probability = (weighed.probability1, weighed.probability2)
    else:
        outcome = confirm(
            candidates,
            evidence,
            calibration.delay_frames,
            calibration.pose,
            calibration.width,
            ctx.separation_m,
            params,
            ctx.params.triangulation,
        )
        accepted = (outcome.accepted1, outcome.accepted2)
        matched = (outcome.stereo1, outcome.stereo2)
        probability = (np.full(len(candidates[0]), np.nan), np.full(len(candidates[1]), np.nan))
    metrics: dict[str, Any] = {"decided_by": "evidence model" if model else "rules"}
    outputs = zip(ctx.paths(FLASHES_CSV), ctx.paths(ACCEPTANCE_NPZ), strict=True)
    for camera, det, ev, keep, stereo, p, (csv, npz) in zip(
        CAMERAS, candidates, evidence, accepted, matched, probability, outputs, strict=True
    ):
        det.select(keep).to_csv(csv)
        np.savez_compressed(npz, probability=p, accepted=keep, matched=stereo)
        metrics[f"cam{camera}"] = acceptance_counts(ev.verdict, keep, stereo)
    return StageResult(metrics=metrics, warnings=[note] if note else [])


def refit(ctx: StageContext) -> StageResult:
    """The pose fitted again on the stereo matches of the accepted flashes
    (`pipeline.pose_refit`): writes ``calibration.json``.

    The first pose's fit is described there under ``first_pose`` and the refit under
    ``refit``. Where the refit is switched off, or the matches are too few or do not
    agree (a warning then), the first pose is the calibration.
    """
    validate_separation(ctx.separation_m)
    first = read_json(ctx.path(POSE_JSON))
    calibration = read_calibration(ctx.path(POSE_JSON))
    params = ctx.params.pose
    fit = {key: first[key] for key in _FIT}
    warnings: list[str] = []
    refitted: dict[str, Any] | None = None
    save_pairs(ctx.path(REFIT_PAIRS_NPZ))
    if params.refit_from_accepted:
        det1, det2 = _accepted(ctx)
        try:
            pairs = stereo_match_pairs(
                det1,
                det2,
                calibration.delay_frames,
                calibration.pose,
                calibration.width,
                ctx.separation_m,
                ctx.params.triangulation,
                params.refit_min_snr,
            )
            estimate = estimate_pose(pairs, params)
        except PoseError as exc:
            warnings.append(f"the pose of the confident flashes is kept, not refitted: {exc}")
        else:
            warnings = [
                *fit_warnings(estimate, calibration.width, params),
                *baseline_warnings(estimate, params),
            ]
            covariance = jackknife_scaled(estimate)
            save_pairs(ctx.path(REFIT_PAIRS_NPZ), pairs.frame1, estimate)
            refitted = {
                "min_snr": params.refit_min_snr,
                "rotation_change_deg": float(
                    np.degrees(rotation_angle(calibration.pose.rotation, estimate.pose.rotation))
                ),
                "translation_change_deg": float(
                    np.degrees(
                        angle_between(calibration.pose.translation, estimate.pose.translation)
                    )
                ),
                "median_residual_px": median_residual_px(estimate, calibration.width),
                "covariance_scale": float(covariance[0, 0] / estimate.covariance[0, 0]),
            }
            calibration = replace(calibration, pose=estimate.pose, covariance=covariance)
            fit = {
                "n_calibration_pairs": estimate.n_pairs,
                "n_calibration_inliers": estimate.n_inliers,
                "residuals": estimate.stats,
            }
    # The first fit's warnings are about the first pose; the delay's stay either way.
    kept = read_json(ctx.path(SYNC_JSON)).get("warnings", []) if refitted else first["warnings"]
    write_calibration(
        ctx.path(CALIBRATION_JSON),
        calibration,
        extra={
            **fit,
            "camera_height_m": first.get("camera_height_m"),
            "first_pose": {key: first[key] for key in _FIRST_POSE},
            "refit": refitted,
            "warnings": [*kept, *warnings],
        },
    )
    metrics = {
        **fit,
        "rotation": calibration.pose.rotation.tolist(),
        "translation": calibration.pose.translation.tolist(),
        "refit": refitted,
    }
    return StageResult(metrics=metrics, warnings=warnings)


def save_pairs(
    path: Path, frame1: NDArray[np.int64] | None = None, estimate: PoseEstimate | None = None
) -> None:
    """Write a pose fit's pairs for the report: camera-1 frame, residual (degrees) and
    inlier flag of each; empty without a fit."""
    if frame1 is None or estimate is None:
        frame1, residuals, inliers = np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool)
    else:
        residuals, inliers = estimate.residuals, estimate.inliers
    np.savez_compressed(path, frame1=frame1, residuals=residuals, inliers=inliers)


#: How well a pose fits its pairs, in ``calibration.json`` (the final fit's).
_FIT = ("n_calibration_pairs", "n_calibration_inliers", "residuals")
#: What ``work/pose.json`` says of the first pose, kept under ``first_pose``.
_FIRST_POSE = ("rotation", "translation", *_FIT, "calibration_min_snr", "pose_fits")


def triangulate(ctx: StageContext) -> StageResult:
    """Match flashes between synchronised frames and triangulate them in metres."""
    validate_separation(ctx.separation_m)
    calibration = read_calibration(ctx.path(CALIBRATION_JSON))
    det1, det2 = _accepted(ctx)
    points = triangulate_points(
        det1,
        det2,
        calibration.delay_frames,
        calibration.pose,
        calibration.width,
        ctx.separation_m,
        ctx.params.triangulation,
        pose_covariance=worst_axis_covariance(
            calibration.pose_covariance, calibration.pose.translation
        ),
    )
    save_points(ctx.path(POINTS_NPZ), points)
    metrics = {
        "n_points": len(points),
        "median_gap_m": float(np.median(points.gap_m)) if len(points) else None,
        "median_range_m": float(np.median(points.range_m)) if len(points) else None,
        "n_points_sure": int(np.count_nonzero(sure_of_range(points.range_sd_m, points.range_m))),
    }
    warnings = [] if len(points) else ["no flash could be triangulated"]
    return StageResult(metrics=metrics, warnings=warnings)


def link(ctx: StageContext) -> StageResult:
    """Link triangulated flashes into streaks and trajectories; write trajectories.csv."""
    points = load_points(ctx.path(POINTS_NPZ))
    linking = link_points(points, ctx.probe.fps, ctx.params.linking)
    clock = NightClock.load(ctx.path(CLOCK_JSON))
    write_trajectories(ctx.path(TRAJECTORIES_CSV), points, linking, ctx.probe.fps, clock)
    metrics = {
        "n_points": len(points),
        "n_streaks": len(np.unique(linking.streak_id)),
        "n_trajectories": len(np.unique(linking.trajectory_id)),
        "n_ambiguous_links": linking.n_ambiguous,
    }
    return StageResult(metrics=metrics)


def clock(ctx: StageContext) -> StageResult:
    """Place camera 1's frame 0 in UTC and find the night's sunset (``work/clock.json``).

    An unknown time is a warning, not a failure: the timestamp columns stay empty.
    """
    found = night_clock(ctx.night, ctx.probe)
    found.save(ctx.path(CLOCK_JSON))
    data = found.to_dict()
    metrics = {key: data[key] for key in data if key != "warnings"}
    return StageResult(metrics=metrics, warnings=list(found.warnings))


def patterns(ctx: StageContext) -> StageResult:
    """Flash patterns per trajectory (``flash_patterns.csv``) and for the night (metrics)."""
    from pipeline.patterns import night_patterns, per_trajectory
    from pipeline.results import read_trajectories, write_flash_patterns

    probe = ctx.probe
    table = read_trajectories(ctx.path(TRAJECTORIES_CSV))
    n_frames = probe.n_frames[1]
    flashes, night = night_patterns(table, probe.fps, n_frames, ctx.params.patterns)
    rows = per_trajectory(table, flashes, probe.fps, ctx.params.patterns, ctx.camera_height_m)
    clock = NightClock.load(ctx.path(CLOCK_JSON))
    write_flash_patterns(ctx.path(FLASH_PATTERNS_CSV), rows, probe.fps, clock)
    warnings = []
    if night["synchronous"] is None and night["n_trajectories"]:
        warnings.append(
            f"synchrony not assessed: {night['n_trajectories']} trajectories, fewer than "
            f"{ctx.params.patterns.min_trajectories}"
        )
    return StageResult(metrics={"night": night}, warnings=warnings)


def report(ctx: StageContext) -> StageResult:
    """Plots and ``summary.json`` of a finished run."""
    from pipeline.report import write_plots  # matplotlib is only needed here

    plots = write_plots(ctx.workdir, ctx.params.patterns)
    records = {u: read_record(ctx.workdir, u) for u in earlier_units(ctx.unit, ctx.units)}
    write_json(ctx.workdir / SUMMARY_JSON, summarise(records, ctx.params))
    return StageResult(metrics={"n_plots": len(plots)})
