"""The stage graph of a run: one declarative table that every runner iterates.

``STAGES`` lists the pipeline's stages in a valid order. Each entry says what the stage
runs on (the whole run, each camera, or each tracking chunk of each camera), which
stages it waits for, which files of the run folder it reads and writes, which input
videos it needs, and where its function is. Three runners iterate the same table:

* the in-process runner of the CLI (`pipeline.run`) calls the units one after the other
  in one folder;
* the service's workflow (`services.core.workflow`) turns units into stage rows and
  queues each one when its prerequisites have succeeded;
* the service's worker (`services.worker.runner`) downloads exactly what a unit reads,
  calls `execute`, and uploads what it wrote.

Adding a stage is one entry here and one function (``StageContext -> StageResult``)::

    probe ─▶ track (chunks × cameras) ─▶ merge (× cameras) ─▶ sync ─▶ pose ─▶ accept
          ─▶ refit ─▶ triangulate ─▶ link ─▶ patterns ─▶ report
      └──▶ clock (the night's real time; needed from link on) ──┘

File names in ``reads`` / ``writes`` are `pipeline.artifacts` templates: ``{camera}``
expands to the unit's camera (to both cameras for a whole-run unit) and
``{start}``/``{stop}`` to the planned chunks (of the unit's camera, if it has one).
`EARLIER_METRICS` stands for the metrics files of every whole-run and per-camera unit
of the stages before.

This module is light (pydantic and the standard library): the API imports it.
"""

from __future__ import annotations

import importlib
import string
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

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
    METRICS_DIR,
    POINTS_NPZ,
    POSE_JSON,
    PROBE_JSON,
    REFIT_PAIRS_NPZ,
    REPORT_DIR,
    SYNC_JSON,
    TRAJECTORIES_CSV,
)
from pipeline.chunking import chunk_ranges, frames_read
from pipeline.jsonio import read_json, write_json
from pipeline.night import NightInfo
from pipeline.params import ProcessParams
from pipeline.probe import StereoProbe

Scope = Literal["run", "camera", "chunk"]
VideoNeed = Literal["none", "all", "chunk"]

#: In `Stage.reads`: the metrics files of every whole-run and per-camera unit before.
EARLIER_METRICS = "<metrics of the earlier stages>"


@dataclass(frozen=True)
class Unit:
    """One runnable piece of a stage: the whole stage, one camera, or one frame range.

    Attributes
    ----------
    stage : str
        Name of the stage (a `STAGES` entry).
    camera : int or None
        1 or 2 for per-camera and chunk units.
    start, stop : int or None
        The global frame range ``[start, stop)`` of a chunk unit.
    """

    stage: str
    camera: int | None = None
    start: int | None = None
    stop: int | None = None

    @property
    def key(self) -> str:
        """Unique within a run: ``sync``, ``merge/cam1``, ``track/cam1/00000000-00001800``."""
        if self.start is not None:
            return f"{self.stage}/cam{self.camera}/{self.start:08d}-{self.stop:08d}"
        return self.stage if self.camera is None else f"{self.stage}/cam{self.camera}"

    @property
    def label(self) -> str:
        """Readable name, e.g. ``track camera 1 frames 0–1800``."""
        if self.start is not None:
            return f"{self.stage} camera {self.camera} frames {self.start}–{self.stop}"
        return self.stage if self.camera is None else f"{self.stage} camera {self.camera}"

    @property
    def slug(self) -> str:
        """Key without slashes (``merge_cam1``), as in timings and metrics file names."""
        return self.key.replace("/", "_")

    @property
    def metrics_name(self) -> str:
        """Where the unit's metrics and warnings are written in the run folder."""
        return self.fill(stage(self.stage).metrics_template)

    def fill(self, template: str) -> str:
        """`template` with this unit's camera and frame range filled in."""
        return template.format(camera=self.camera, start=self.start, stop=self.stop)


@dataclass
class StageResult:
    """What a stage measured; ``outputs`` (names written) is filled in by `execute`."""

    metrics: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    outputs: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class StageContext:
    """Everything a stage function gets: its unit, the run's inputs and parameters.

    ``videos`` maps camera to ``{chapter index: local file}`` and holds at least the
    chapters `chapters_needed` names for the unit. The run folder ``workdir`` holds the
    files the unit reads (`reads`) and receives what it writes. ``night`` is what is
    known about the recording session (site, place, time zone…; `pipeline.night`).
    """

    workdir: Path
    unit: Unit
    params: ProcessParams
    separation_m: float
    camera_height_m: float | None = None
    night: NightInfo = field(default_factory=NightInfo)
    videos: Mapping[int, Mapping[int, Path]] = field(default_factory=dict)
    progress: Callable[[float], None] = field(default=lambda fraction: None)
    stages: Sequence[Stage] = field(default_factory=lambda: STAGES)

    @cached_property
    def probe(self) -> StereoProbe:
        """The recording's probe, read once from ``work/probe.json``."""
        return StereoProbe.load(self.workdir)

    @cached_property
    def units(self) -> list[Unit]:
        """Every unit of the run's stages, tracking chunks included."""
        return plan(self.probe, self.params, self.stages)

    def path(self, template: str) -> Path:
        """The run-folder path of a file of this unit (its camera filled in)."""
        return self.workdir / self.unit.fill(template)

    def paths(self, template: str) -> list[Path]:
        """The run-folder paths a template expands to for this unit (see `resolve`)."""
        # Only chunk names need the probe (to plan the chunks).
        units = self.units if is_chunk_template(template) else plan(None, self.params, self.stages)
        return [self.workdir / name for name in resolve(template, self.unit, units)]


StageFunction = Callable[[StageContext], StageResult]


@dataclass(frozen=True)
class Stage:
    """One entry of the stage graph.

    Attributes
    ----------
    name : str
        Stage name (also the service's task and row name).
    function : str
        ``"module:function"`` of the stage function, imported when it first runs (so
        that the graph itself loads no science library).
    scope : {"run", "camera", "chunk"}
        One unit per run, per camera, or per planned tracking chunk of each camera.
    after : tuple of str
        Stages whose units must have succeeded first (same camera where both have one).
    reads, writes : tuple of str
        Run-folder files (`pipeline.artifacts` templates, or `EARLIER_METRICS`).
    videos : {"none", "all", "chunk"}
        Input videos a unit needs: none, every chapter of both cameras, or the chapters
        its frame range decodes.
    description : str
        One line for people.
    """

    name: str
    function: str
    scope: Scope = "run"
    after: tuple[str, ...] = ()
    reads: tuple[str, ...] = ()
    writes: tuple[str, ...] = ()
    videos: VideoNeed = "none"
    description: str = ""

    @property
    def metrics_template(self) -> str:
        """Where each unit of the stage records its metrics (a template)."""
        if self.scope == "chunk":
            return CHUNK_METRICS_JSON
        suffix = "_cam{camera}" if self.scope == "camera" else ""
        return f"{METRICS_DIR}/{self.name}{suffix}.json"

    def load(self) -> StageFunction:
        module, attribute = self.function.split(":")
        function: StageFunction = getattr(importlib.import_module(module), attribute)
        return function


STAGES: tuple[Stage, ...] = (
    Stage(
        "probe",
        "pipeline.stages:probe",
        videos="all",
        writes=(PROBE_JSON,),
        description="read both cameras' chapter files; check they form a stereo pair",
    ),
    Stage(
        "track",
        "pipeline.stages:track",
        scope="chunk",
        after=("probe",),
        videos="chunk",
        reads=(PROBE_JSON,),
        writes=(CHUNK_NPZ, FAINT_CHUNK_NPZ),
        description="find and classify flash candidates in one frame range of one camera",
    ),
    Stage(
        "merge",
        "pipeline.stages:merge",
        scope="camera",
        after=("track",),
        reads=(PROBE_JSON, CHUNK_NPZ, FAINT_CHUNK_NPZ, CHUNK_METRICS_JSON),
        writes=(CANDIDATES_NPZ, EVIDENCE_NPZ),
        description="join a camera's chunks and weigh each candidate's own evidence",
    ),
    Stage(
        "sync",
        "pipeline.stages:sync",
        after=("merge",),
        reads=(PROBE_JSON, CANDIDATES_NPZ, EVIDENCE_NPZ),
        writes=(SYNC_JSON,),
        description="frame delay between the cameras from their confident flash counts",
    ),
    Stage(
        "pose",
        "pipeline.stages:pose",
        after=("sync",),
        reads=(PROBE_JSON, SYNC_JSON, CANDIDATES_NPZ, EVIDENCE_NPZ),
        writes=(POSE_JSON, CALIBRATION_PAIRS_NPZ),
        description="relative pose of the cameras from frames with one confident flash each",
    ),
    Stage(
        "accept",
        "pipeline.stages:accept",
        after=("pose",),
        reads=(PROBE_JSON, POSE_JSON, CANDIDATES_NPZ, EVIDENCE_NPZ),
        writes=(FLASHES_CSV, ACCEPTANCE_NPZ),
        description="accept the flashes from all the evidence, the other camera's included",
    ),
    Stage(
        "refit",
        "pipeline.stages:refit",
        after=("accept",),
        reads=(SYNC_JSON, POSE_JSON, FLASHES_CSV),
        writes=(CALIBRATION_JSON, REFIT_PAIRS_NPZ),
        description="the pose fitted again on the stereo matches of every accepted flash",
    ),
    Stage(
        "triangulate",
        "pipeline.stages:triangulate",
        after=("refit",),
        reads=(CALIBRATION_JSON, FLASHES_CSV),
        writes=(POINTS_NPZ,),
        description="match flashes between synchronised frames and triangulate them",
    ),
    Stage(
        "clock",
        "pipeline.stages:clock",
        after=("probe",),
        reads=(PROBE_JSON,),
        writes=(CLOCK_JSON,),
        description="place the recording in real time (UTC) and find the night's sunset",
    ),
    Stage(
        "link",
        "pipeline.stages:link",
        after=("triangulate", "clock"),
        reads=(PROBE_JSON, POINTS_NPZ, CLOCK_JSON),
        writes=(TRAJECTORIES_CSV,),
        description="link 3D flashes into streaks and trajectories",
    ),
    Stage(
        "patterns",
        "pipeline.stages:patterns",
        after=("link",),
        reads=(PROBE_JSON, CLOCK_JSON, TRAJECTORIES_CSV),
        writes=(FLASH_PATTERNS_CSV,),
        description="flash durations, inter-flash intervals, trains, period and synchrony",
    ),
    Stage(
        "report",
        "pipeline.stages:report",
        after=("patterns",),
        reads=(
            PROBE_JSON,
            SYNC_JSON,
            CALIBRATION_JSON,
            CALIBRATION_PAIRS_NPZ,
            REFIT_PAIRS_NPZ,
            TRAJECTORIES_CSV,
            FLASHES_CSV,
            CLOCK_JSON,
            FLASH_PATTERNS_CSV,
            EARLIER_METRICS,
        ),
        writes=(REPORT_DIR,),
        description="plots and the run summary",
    ),
)

STAGE_NAMES: tuple[str, ...] = tuple(s.name for s in STAGES)
_BY_NAME = {s.name: s for s in STAGES}


def stage(name: str) -> Stage:
    """The graph entry of a stage.

    Raises
    ------
    ValueError
        For an unknown name (the message lists the stages).
    """
    try:
        return _BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown stage {name!r}; stages are {', '.join(STAGE_NAMES)}") from None


def stages_from(name: str) -> tuple[Stage, ...]:
    """`STAGES` from `name` on."""
    return STAGES[STAGE_NAMES.index(stage(name).name) :]


def producer(name: str) -> Stage:
    """The stage that writes the run-folder file (or template) `name`."""
    for entry in STAGES:
        if name in (*entry.writes, entry.metrics_template):
            return entry
    raise ValueError(f"no stage writes {name!r}")


def position(unit: Unit) -> tuple[int, int, int]:
    """Sort key of units in pipeline order (stage, camera, first frame)."""
    return STAGE_NAMES.index(unit.stage), unit.camera or 0, unit.start or 0


def plan(
    probe: StereoProbe | None, params: ProcessParams, stages: Sequence[Stage] = STAGES
) -> list[Unit]:
    """Every unit of `stages`, in pipeline order.

    Chunk units need the probe (the cameras' lengths); without one (before the probe
    stage has run) they are left out and planned later.
    """
    units: list[Unit] = []
    for entry in stages:
        if entry.scope == "run":
            units.append(Unit(entry.name))
        elif entry.scope == "camera":
            units += [Unit(entry.name, camera) for camera in CAMERAS]
        elif probe is not None:
            units += [
                Unit(entry.name, camera, start, stop)
                for camera in CAMERAS
                for start, stop in chunk_ranges(
                    probe.n_frames[camera], probe.fps, params.tracking, params.chunk_s
                )
            ]
    return units


def prerequisites(unit: Unit, units: Iterable[Unit]) -> list[Unit] | None:
    """Units that must succeed before `unit` runs; None while they are not planned yet.

    A dependency on a per-camera or chunk stage is on the same camera's units when
    `unit` has a camera, on both cameras' otherwise.
    """
    units = list(units)
    needed: list[Unit] = []
    for name in stage(unit.stage).after:
        rows = [
            u
            for u in units
            if u.stage == name and (unit.camera is None or u.camera in (None, unit.camera))
        ]
        if not rows:
            return None
        needed += rows
    return needed


def earlier_units(unit: Unit, units: Iterable[Unit]) -> list[Unit]:
    """Whole-run and per-camera units of the stages before `unit`'s, in pipeline order."""
    first = STAGE_NAMES.index(unit.stage)
    return sorted(
        (u for u in units if u.start is None and STAGE_NAMES.index(u.stage) < first),
        key=position,
    )


def is_chunk_template(template: str) -> bool:
    """Whether a file name template names tracking chunks (it has a ``{start}`` field)."""
    return "start" in {name for _, name, _, _ in string.Formatter().parse(template) if name}


def resolve(template: str, unit: Unit, units: Iterable[Unit]) -> list[str]:
    """The run-folder names a `reads` / `writes` entry stands for, for `unit`."""
    units = list(units)
    if template == EARLIER_METRICS:
        return [u.metrics_name for u in earlier_units(unit, units)]
    if is_chunk_template(template):
        chunks = [
            u
            for u in units
            if u.start is not None and (unit.camera is None or u.camera == unit.camera)
        ]
        return [u.fill(template) for u in sorted(chunks, key=position)]
    if "{camera" in template and unit.camera is None:
        return [template.format(camera=camera) for camera in CAMERAS]
    return [unit.fill(template)]


def reads(unit: Unit, units: Iterable[Unit]) -> list[str]:
    """Every run-folder file `unit` reads."""
    units = list(units)
    return [name for template in stage(unit.stage).reads for name in resolve(template, unit, units)]


def writes(unit: Unit) -> list[str]:
    """Every run-folder file or folder `unit` writes, its metrics file last."""
    declared = stage(unit.stage).writes
    return [*(name for t in declared for name in resolve(t, unit, [unit])), unit.metrics_name]


def chunk_chapters(unit: Unit, probe: StereoProbe, params: ProcessParams) -> list[int]:
    """Indices of the chapter files a chunk unit decodes (its range and warm-up)."""
    if unit.camera is None or unit.start is None or unit.stop is None:
        raise ValueError(f"{unit.label} is not a frame range of one camera")
    first, stop = frames_read(unit.start, unit.stop, probe.fps, params.tracking)
    return list(probe.videos[unit.camera].chapters_for(first, stop))


def execute(entry: Stage, context: StageContext) -> StageResult:
    """Run one unit: call the stage function, record its metrics, list what it wrote.

    The metrics (with the unit's ``seconds``) and warnings are written to the unit's
    metrics file; ``outputs`` lists every declared output and that file.

    Raises
    ------
    RuntimeError
        If the stage did not write a file it declares (a bug, not bad input).
    """
    started = time.perf_counter()
    result = entry.load()(context)
    outcome = record(context.workdir, context.unit, result, time.perf_counter() - started)
    missing = [name for name in outcome.outputs if not (context.workdir / name).exists()]
    if missing:
        raise RuntimeError(f"{context.unit.label} did not write {', '.join(missing)}")
    return outcome


def record(workdir: Path, unit: Unit, result: StageResult, seconds: float) -> StageResult:
    """Write a unit's metrics file; return the result with its timing and outputs."""
    metrics = {**result.metrics, "seconds": seconds}
    write_json(workdir / unit.metrics_name, {"metrics": metrics, "warnings": result.warnings})
    return StageResult(metrics=metrics, warnings=list(result.warnings), outputs=writes(unit))


def read_record(workdir: Path, unit: Unit) -> StageResult:
    """The metrics and warnings a unit recorded (`record`) in a run folder."""
    data = read_json(workdir / unit.metrics_name)
    return StageResult(metrics=data["metrics"], warnings=list(data.get("warnings", [])))
