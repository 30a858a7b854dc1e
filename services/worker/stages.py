"""Stage bodies: fetch a stage's inputs, call its `pipeline.run` function.

No science here: each body only maps a stage row to the pipeline's stage function and
its files.
"""

from __future__ import annotations

from pathlib import Path

from pipeline import run
from pipeline.artifacts import CAMERAS, PROBE_JSON
from services.worker.inputs import InputRef, fetch_artifact
from services.worker.runner import Progress, Runtime, StageBody, StageContext


def _input_path(workdir: Path, ref: InputRef) -> Path:
    # The team's own file name, so that the pipeline's error messages name it.
    return workdir / "input" / f"cam{ref.camera}" / f"{ref.chapter:02d}" / ref.filename


def _fetch_inputs(
    ctx: StageContext, workdir: Path, rt: Runtime, refs: list[InputRef]
) -> dict[int, Path]:
    return {ref.chapter: rt.cache.fetch(rt.storage, ref, _input_path(workdir, ref)) for ref in refs}


def probe(ctx: StageContext, workdir: Path, rt: Runtime, progress: Progress) -> run.StageResult:
    """Download (and verify) every chapter, then probe both cameras."""
    videos = {
        camera: _fetch_inputs(ctx, workdir, rt, [r for r in ctx.inputs if r.camera == camera])
        for camera in CAMERAS
    }
    return run.probe_stage(
        [videos[1][c] for c in sorted(videos[1])],
        [videos[2][c] for c in sorted(videos[2])],
        workdir,
    )


def track(ctx: StageContext, workdir: Path, rt: Runtime, progress: Progress) -> run.StageResult:
    """Track one frame range of one camera, downloading only the chapters it reads."""
    assert ctx.camera is not None and ctx.start is not None and ctx.stop is not None
    fetch_artifact(rt.storage, ctx.job_id, PROBE_JSON, workdir)
    needed = run.chapters_needed(workdir, ctx.camera, ctx.start, ctx.stop, ctx.params)
    refs = [r for r in ctx.inputs if r.camera == ctx.camera and r.chapter in needed]
    videos = _fetch_inputs(ctx, workdir, rt, refs)
    return run.track_chunk_stage(
        workdir, ctx.camera, ctx.start, ctx.stop, videos, ctx.params, progress=progress
    )


def _with_inputs(ctx: StageContext, workdir: Path, rt: Runtime) -> None:
    fetch_artifact(rt.storage, ctx.job_id, PROBE_JSON, workdir)
    for name in run.stage_inputs(ctx.name, workdir, ctx.params, ctx.camera):
        if name != PROBE_JSON:
            fetch_artifact(rt.storage, ctx.job_id, name, workdir)


def merge(ctx: StageContext, workdir: Path, rt: Runtime, progress: Progress) -> run.StageResult:
    assert ctx.camera is not None
    _with_inputs(ctx, workdir, rt)
    return run.merge_stage(workdir, ctx.camera, ctx.params)


def sync(ctx: StageContext, workdir: Path, rt: Runtime, progress: Progress) -> run.StageResult:
    _with_inputs(ctx, workdir, rt)
    return run.sync_stage(workdir, ctx.params)


def pose(ctx: StageContext, workdir: Path, rt: Runtime, progress: Progress) -> run.StageResult:
    _with_inputs(ctx, workdir, rt)
    return run.pose_stage(workdir, ctx.params, ctx.separation_m, ctx.height_m)


def triangulate(
    ctx: StageContext, workdir: Path, rt: Runtime, progress: Progress
) -> run.StageResult:
    _with_inputs(ctx, workdir, rt)
    return run.triangulate_stage(workdir, ctx.params, ctx.separation_m)


def link(ctx: StageContext, workdir: Path, rt: Runtime, progress: Progress) -> run.StageResult:
    _with_inputs(ctx, workdir, rt)
    return run.link_stage(workdir, ctx.params)


def report(ctx: StageContext, workdir: Path, rt: Runtime, progress: Progress) -> run.StageResult:
    _with_inputs(ctx, workdir, rt)
    return run.report_stage(workdir, ctx.params)


BODIES: dict[str, StageBody] = {
    "probe": probe,
    "track": track,
    "merge": merge,
    "sync": sync,
    "pose": pose,
    "triangulate": triangulate,
    "link": link,
    "report": report,
}
