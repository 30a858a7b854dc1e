"""The stage graph: a consistent table, planning, prerequisites and file expansion."""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest

from pipeline import graph
from pipeline.artifacts import CHUNK_NPZ, FLASHES_CSV, PROBE_JSON
from pipeline.graph import EARLIER_METRICS, STAGE_NAMES, STAGES, StageContext, Unit
from pipeline.params import ProcessParams
from pipeline.probe import StereoProbe

PARAMS = ProcessParams.model_validate({"chunk_s": 6, "tracking": {"block_s": 6}})
PROBE = StereoProbe(width=640, height=320, fps=30.0, n_frames={1: 600, 2: 450})


def test_every_stage_waits_for_earlier_stages_and_reads_what_they_write() -> None:
    assert len(set(STAGE_NAMES)) == len(STAGES)
    for index, entry in enumerate(STAGES):
        assert all(STAGE_NAMES.index(name) < index for name in entry.after), entry.name
        for template in entry.reads:
            if template != EARLIER_METRICS:
                assert STAGE_NAMES.index(graph.producer(template).name) < index, template


def test_every_stage_function_exists_and_takes_a_context() -> None:
    for entry in STAGES:
        function = entry.load()
        assert list(inspect.signature(function).parameters) == ["ctx"], entry.function


def test_plan_leaves_chunks_until_the_probe_is_known() -> None:
    static = graph.plan(None, PARAMS)
    assert [u.key for u in static] == [
        "probe",
        "merge/cam1",
        "merge/cam2",
        "sync",
        "pose",
        "accept",
        "refit",
        "triangulate",
        "clock",
        "link",
        "patterns",
        "report",
    ]
    chunks = [u for u in graph.plan(PROBE, PARAMS) if u.stage == "track"]
    assert [(u.camera, u.start, u.stop) for u in chunks] == [
        (1, 0, 180),
        (1, 180, 360),
        (1, 360, 540),
        (1, 540, 600),
        (2, 0, 180),
        (2, 180, 360),
        (2, 360, 450),
    ]


def test_prerequisites_follow_cameras() -> None:
    units = graph.plan(PROBE, PARAMS)
    keys = lambda us: [u.key for u in us]  # noqa: E731
    assert keys(graph.prerequisites(Unit("track", 2, 0, 180), units) or []) == ["probe"]
    merge2 = graph.prerequisites(Unit("merge", 2), units) or []
    assert keys(merge2) == [
        f"track/cam2/{a:08d}-{b:08d}" for a, b in ((0, 180), (180, 360), (360, 450))
    ]
    assert keys(graph.prerequisites(Unit("sync"), units) or []) == ["merge/cam1", "merge/cam2"]
    assert graph.prerequisites(Unit("probe"), units) == []
    assert graph.prerequisites(Unit("merge", 1), graph.plan(None, PARAMS)) is None


def test_templates_expand_per_unit() -> None:
    units = graph.plan(PROBE, PARAMS)
    assert graph.resolve(FLASHES_CSV, Unit("merge", 2), units) == ["flashes_cam2.csv"]
    assert graph.resolve(FLASHES_CSV, Unit("sync"), units) == [
        "flashes_cam1.csv",
        "flashes_cam2.csv",
    ]
    assert graph.resolve(CHUNK_NPZ, Unit("merge", 2), units) == [
        "work/tracking/cam2/00000000-00000180.npz",
        "work/tracking/cam2/00000180-00000360.npz",
        "work/tracking/cam2/00000360-00000450.npz",
    ]
    assert graph.resolve(PROBE_JSON, Unit("sync"), units) == [PROBE_JSON]
    assert graph.resolve(EARLIER_METRICS, Unit("sync"), units) == [
        "work/metrics/probe.json",
        "work/metrics/merge_cam1.json",
        "work/metrics/merge_cam2.json",
    ]
    assert graph.writes(Unit("track", 1, 0, 180)) == [
        "work/tracking/cam1/00000000-00000180.npz",
        "work/tracking/cam1/faint/00000000-00000180.npz",
        "work/tracking/cam1/00000000-00000180.json",
    ]


def test_no_two_units_write_the_same_file() -> None:
    written = [name for unit in graph.plan(PROBE, PARAMS) for name in graph.writes(unit)]
    assert len(written) == len(set(written))


def test_units_name_themselves() -> None:
    chunk = Unit("track", 1, 0, 1800)
    assert (chunk.key, chunk.label, chunk.slug) == (
        "track/cam1/00000000-00001800",
        "track camera 1 frames 0–1800",
        "track_cam1_00000000-00001800",
    )
    assert (Unit("merge", 2).key, Unit("merge", 2).label) == ("merge/cam2", "merge camera 2")
    with pytest.raises(ValueError, match="unknown stage 'calibrate'; stages are probe, track"):
        graph.stage("calibrate")


def test_a_unit_finds_its_files_without_the_probe_unless_it_reads_chunks(tmp_path: Path) -> None:
    """A worker fetches only what a unit reads: triangulation has no probe.json."""
    context = StageContext(
        workdir=tmp_path, unit=Unit("triangulate"), params=PARAMS, separation_m=1.5
    )
    assert context.paths(FLASHES_CSV) == [
        tmp_path / "flashes_cam1.csv",
        tmp_path / "flashes_cam2.csv",
    ]
    merge = StageContext(workdir=tmp_path, unit=Unit("merge", 1), params=PARAMS, separation_m=1.5)
    PROBE.save(tmp_path)
    assert len(merge.paths(CHUNK_NPZ)) == 4
