"""Runs the stage graph in this process, in one run folder (what the CLI does).

`process` starts from the two cameras' videos and runs every stage of
`pipeline.graph.STAGES`; `reconstruct` starts from per-camera detections and runs the
stages after ``merge``. Both iterate the same graph as the service's workers, call the
same stage functions through `pipeline.graph.execute`, and leave the same files.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

from pipeline.graph import (
    STAGES,
    Stage,
    StageContext,
    StageResult,
    Unit,
    execute,
    plan,
    record,
    stage,
    stages_from,
)
from pipeline.night import NightInfo
from pipeline.params import ProcessParams, validate_separation
from pipeline.probe import StereoProbe

#: Called with a stage label (e.g. "track cam1") and the fraction of it done.
RunProgress = Callable[[str, float], None]


@dataclass
class RunOutcome:
    """Every unit's result of an in-process run, by unit key, in the order they ran."""

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
    night: NightInfo | None = None,
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
    night : NightInfo, optional
        What is known about the night (site, place, time zone, start time…).
    """
    validate_separation(separation_m)
    out_dir.mkdir(parents=True, exist_ok=True)
    context = StageContext(
        workdir=out_dir,
        unit=Unit("probe"),
        params=params or ProcessParams(),
        separation_m=separation_m,
        camera_height_m=camera_height_m,
        night=night or NightInfo(),
        videos={1: dict(enumerate(cam1)), 2: dict(enumerate(cam2))},
    )
    return run_stages(STAGES, context, progress)


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
    night: NightInfo | None = None,
    camera_height_m: float | None = None,
) -> RunOutcome:
    """Run the stages after ``merge`` from per-camera detections (``frame,x,y`` CSVs).

    The detections are taken as flashes (those with an ``snr`` column below
    ``acceptance.confident_snr`` need stereo confirmation, as candidates of our own
    tracker do); the probe is made from the frame size and rate given.
    """
    from pipeline.detections import Detections
    from pipeline.stages import import_detections, probe_detections

    validate_separation(separation_m)
    params = params or ProcessParams()
    out_dir.mkdir(parents=True, exist_ok=True)
    det1, det2 = Detections.from_csv(flashes1), Detections.from_csv(flashes2)
    import_detections({1: det1, 2: det2}, out_dir, width, params.acceptance)
    probed = probe_detections(det1, det2, width, height, fps, out_dir)
    outcome = RunOutcome(out_dir)
    outcome.results["probe"] = record(out_dir, Unit("probe"), probed, 0.0)
    context = StageContext(
        workdir=out_dir,
        unit=Unit("probe"),
        params=params,
        separation_m=separation_m,
        camera_height_m=camera_height_m,
        night=night or NightInfo(),
        stages=(stage("probe"), *stages_from("sync")),
    )
    return run_stages(stages_from("sync"), context, progress, outcome)


def run_stages(
    stages: Sequence[Stage],
    context: StageContext,
    progress: RunProgress | None = None,
    outcome: RunOutcome | None = None,
) -> RunOutcome:
    """Run every unit of `stages` in order, in ``context.workdir``.

    `context` carries the run's inputs; its unit is replaced by each unit in turn.
    Chunk units are planned once the probe has run.
    """
    report = progress or (lambda label, fraction: None)
    outcome = outcome or RunOutcome(context.workdir)
    for entry in stages:
        probe = StereoProbe.load(context.workdir) if entry.scope == "chunk" else None
        units = plan(probe, context.params, [entry])
        for label, group in _progress_groups(units).items():
            fraction = _group_progress(report, label, group)
            report(label, 0.0)
            for unit in group:
                unit_context = _for_unit(context, unit, partial(fraction, unit))
                outcome.results[unit.key] = execute(entry, unit_context)
                fraction(unit, 1.0)
    return outcome


def _for_unit(context: StageContext, unit: Unit, progress: Callable[[float], None]) -> StageContext:
    # A fresh context (its cached probe and plan are not carried over: the probe may
    # only now have been written).
    return replace(context, unit=unit, progress=progress)


def _progress_groups(units: Sequence[Unit]) -> Mapping[str, list[Unit]]:
    """Units under one progress bar: a stage, or a per-camera stage's camera."""
    groups: dict[str, list[Unit]] = {}
    for unit in units:
        label = unit.stage if unit.camera is None else f"{unit.stage} cam{unit.camera}"
        groups.setdefault(label, []).append(unit)
    return groups


def _group_progress(
    report: RunProgress, label: str, units: Sequence[Unit]
) -> Callable[[Unit, float], None]:
    """Turn "fraction f of a unit done" into the fraction of the group done (frames weigh
    chunks; other units count equally)."""
    sizes = [(u.stop - u.start) if u.start is not None and u.stop is not None else 1 for u in units]
    total = max(sum(sizes), 1)
    before = {u.key: sum(sizes[:i]) for i, u in enumerate(units)}
    size = {u.key: s for u, s in zip(units, sizes, strict=True)}
    return lambda unit, f: report(label, (before[unit.key] + f * size[unit.key]) / total)
