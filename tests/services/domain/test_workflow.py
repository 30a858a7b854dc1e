"""The job/stage state machine against the real database (the broker replaced by a list)."""

from __future__ import annotations

import datetime as dt
import uuid
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import pytest
from sqlalchemy import delete

from pipeline import graph
from pipeline.artifacts import PROBE_JSON, REFIT_PAIRS_NPZ
from pipeline.graph import STAGE_NAMES
from pipeline.params import ProcessParams
from pipeline.probe import StereoProbe
from services.core.db import SessionFactory, transaction
from services.core.models import Artifact, InputFile, Job, Night, Stage, Team
from services.core.storage.local import LocalStorage
from services.domain import workflow
from services.domain.errors import Conflict
from services.domain.repositories import jobs
from services.domain.states import finish_job
from services.domain.workflow import EnqueueError, StageMessage
from tests.services.helpers import artifact_row, record_outputs

T = TypeVar("T")
PARAMS = {"chunk_s": 6, "tracking": {"block_s": 6}, "classifier": {"enabled": False}}


class Broker:
    """Records what `advance` sends."""

    def __init__(self) -> None:
        self.sent: list[StageMessage] = []

    def __call__(self, messages: list[StageMessage]) -> None:
        self.sent.extend(messages)

    def sent_keys(self) -> list[str]:
        return [m.key for m in self.sent]

    def take(self) -> list[str]:
        keys, self.sent = self.sent_keys(), []
        return keys


@pytest.fixture
def storage(tmp_path: Path) -> LocalStorage:
    return LocalStorage(tmp_path / "store")


@pytest.fixture
def job_id(sessions: SessionFactory, storage: LocalStorage, tmp_path: Path) -> uuid.UUID:
    """An uploaded job whose probe says: 600 frames per camera at 30 fps."""
    params = ProcessParams.model_validate(PARAMS).model_dump(mode="json")
    with transaction(sessions) as session:
        team = Team(name=f"wf-{uuid.uuid4().hex[:8]}")
        night = Night(team=team, site="s", date=dt.date(2026, 6, 1), separation_m=1.5, notes="")
        job = Job(id=uuid.uuid4(), night=night, status="uploading", params=params)
        job.files = [
            InputFile(
                camera=c,
                chapter=0,
                filename="a.mp4",
                size=1,
                sha256="0" * 64,
                storage_key=f"k{c}",
                part_size=1,
                upload_state="uploaded",
            )
            for c in (1, 2)
        ]
        session.add(job)
    StereoProbe(width=640, height=320, fps=30.0, n_frames={1: 600, 2: 600}).save(tmp_path)
    storage.upload_file(
        tmp_path / PROBE_JSON, workflow.job_key(job.id, PROBE_JSON), "application/json"
    )
    return job.id


def call(sessions: SessionFactory, action: Callable[..., T], *args: Any) -> T:
    """A workflow action in a session of its own, as a request or a task would run it."""
    with sessions() as session:
        return action(session, *args)


def statuses(sessions: SessionFactory, job_id: uuid.UUID) -> dict[str, str]:
    with sessions() as session:
        return {s.key: s.status for s in session.get_one(Job, job_id).stages}


def finish(
    sessions: SessionFactory, job_id: uuid.UUID, keys: list[str], status: str = "succeeded"
) -> None:
    """End these stages as a worker would, recording a succeeded unit's outputs as artifacts."""
    with transaction(sessions) as session:
        for stage in session.get_one(Job, job_id).stages:
            if stage.key in keys:
                stage.status, stage.attempt = status, stage.attempt + 1
                if status == "succeeded":
                    session.flush()
                    record_outputs(session, job_id, stage)


def test_stages_run_in_dependency_order(
    sessions: SessionFactory, storage: LocalStorage, job_id: uuid.UUID
) -> None:
    broker = Broker()
    call(sessions, workflow.submit, storage, broker, job_id)
    assert broker.take() == ["probe"]
    assert Counter(statuses(sessions, job_id).values()) == {"queued": 1, "pending": 11}

    finish(sessions, job_id, ["probe"])
    call(sessions, workflow.advance, storage, broker, job_id)
    chunks = [
        f"track/cam{c}/{a:08d}-{b:08d}"
        for c in (1, 2)
        for a, b in ((0, 180), (180, 360), (360, 540), (540, 600))
    ]
    assert sorted(broker.take()) == sorted([*chunks, "clock"])  # the clock needs the probe only

    finish(sessions, job_id, [*chunks[:4], "clock"])  # camera 1 done: only its merge may start
    call(sessions, workflow.advance, storage, broker, job_id)
    assert broker.take() == ["merge/cam1"]
    finish(sessions, job_id, [*chunks[4:], "merge/cam1"])
    call(sessions, workflow.advance, storage, broker, job_id)
    assert broker.take() == ["merge/cam2"]

    for previous, following in [
        ("merge/cam2", "sync"),
        ("sync", "pose"),
        ("pose", "accept"),
        ("accept", "refit"),
        ("refit", "triangulate"),
        ("triangulate", "link"),
        ("link", "patterns"),
        ("patterns", "report"),
    ]:
        finish(sessions, job_id, [previous])
        call(sessions, workflow.advance, storage, broker, job_id)
        call(sessions, workflow.advance, storage, broker, job_id)  # idempotent: queued once
        assert broker.take() == [following]
    finish(sessions, job_id, ["report"])
    call(sessions, workflow.advance, storage, broker, job_id)
    with sessions() as session:
        job = session.get_one(Job, job_id)
        assert job.status == "succeeded" and job.finished_at is not None
    assert broker.take() == []


def test_messages_carry_a_fresh_token_per_queueing(
    sessions: SessionFactory, storage: LocalStorage, job_id: uuid.UUID
) -> None:
    broker = Broker()
    call(sessions, workflow.submit, storage, broker, job_id)
    (message,) = broker.sent
    with sessions() as session:
        probe = next(s for s in session.get_one(Job, job_id).stages if s.key == "probe")
        assert (message.job_id, message.token) == (str(job_id), probe.queue_token)
    with pytest.raises(Conflict, match="only a new job can be submitted"):
        call(sessions, workflow.submit, storage, broker, job_id)


def test_broker_refusal_puts_stages_back_to_pending(
    sessions: SessionFactory, storage: LocalStorage, job_id: uuid.UUID
) -> None:
    def refuse(messages: list[StageMessage]) -> None:
        raise ConnectionError("redis is down")

    with pytest.raises(EnqueueError, match="redis is down"):
        call(sessions, workflow.submit, storage, refuse, job_id)
    assert statuses(sessions, job_id)["probe"] == "pending"
    broker = Broker()
    call(sessions, workflow.advance, storage, broker, job_id)  # a later advance recovers
    assert broker.take() == ["probe"]


def test_cancel_stops_waiting_stages(
    sessions: SessionFactory, storage: LocalStorage, job_id: uuid.UUID
) -> None:
    call(sessions, workflow.submit, storage, Broker(), job_id)
    call(sessions, workflow.cancel, job_id)
    assert set(statuses(sessions, job_id).values()) == {"cancelled"}
    with sessions() as session:
        assert all(s.queue_token is None for s in session.get_one(Job, job_id).stages)
    with pytest.raises(Conflict, match="already finished"):
        call(sessions, workflow.cancel, job_id)


def add_artifact(
    sessions: SessionFactory,
    storage: LocalStorage,
    job_id: uuid.UUID,
    key: str,
    name: str,
    tmp: Path,
) -> str:
    path = tmp / name.replace("/", "_")
    path.write_text(name)
    storage_key = workflow.job_key(job_id, name)
    storage.upload_file(path, storage_key, "text/plain")
    with transaction(sessions) as session:
        stage = next(s for s in session.get_one(Job, job_id).stages if s.key == key)
        jobs.save_artifact(session, artifact_row(job_id, stage.id, name, path.stat().st_size))
    return storage_key


def run_to_failure(
    sessions: SessionFactory, storage: LocalStorage, job_id: uuid.UUID, failing: str | None
) -> None:
    """Submit, succeed every stage before `failing`, fail it (None: succeed them all)."""
    broker = Broker()
    call(sessions, workflow.submit, storage, broker, job_id)
    drive(sessions, storage, broker, job_id, failing)


def drive(
    sessions: SessionFactory,
    storage: LocalStorage,
    broker: Broker,
    job_id: uuid.UUID,
    failing: str | None = None,
) -> None:
    """Succeed what the broker was sent, and what follows, until `failing` (failed)."""
    while keys := broker.take():
        if failing in keys:
            with transaction(sessions) as session:
                job = session.get_one(Job, job_id)
                next(s for s in job.stages if s.key == failing).status = "failed"
                finish_job(job, "failed", f"{failing} failed")
            return
        finish(sessions, job_id, keys)
        call(sessions, workflow.advance, storage, broker, job_id)


def test_rerun_reuses_earlier_stages(
    sessions: SessionFactory, storage: LocalStorage, job_id: uuid.UUID, tmp_path: Path
) -> None:
    run_to_failure(sessions, storage, job_id, "pose")
    kept = add_artifact(sessions, storage, job_id, "sync", "work/sync.json", tmp_path)
    stale = add_artifact(sessions, storage, job_id, "pose", "calibration.json", tmp_path)
    with sessions() as session:
        before = {s.key: (s.attempt, s.status) for s in session.get_one(Job, job_id).stages}

    broker = Broker()
    assert call(sessions, workflow.rerun, storage, broker, job_id) == "pose"
    # The clock sits after triangulate in the graph (re-running from it redoes only what
    # reads it) and waits for the probe alone: reset with the later stages, it runs at once.
    assert broker.take() == ["pose", "clock"]
    with sessions() as session:
        job = session.get_one(Job, job_id)
        after = {s.key: (s.attempt, s.status) for s in job.stages}
        assert job.status == "queued" and job.error is None
        names = {a.name for a in job.artifacts}
        assert "work/sync.json" in names and "calibration.json" not in names
        stage_of = {s.id: s.name for s in job.stages}
        kept_stages = {stage_of[a.stage_id] for a in job.artifacts}
        assert kept_stages == {"probe", "track", "merge", "sync"}
    for key, (attempt, status) in before.items():
        if key in ("pose", "accept", "refit", "triangulate", "clock", "link", "patterns", "report"):
            assert after[key] == (attempt, "queued" if key in ("pose", "clock") else "pending")
        else:
            assert after[key] == (attempt, status) == (1, "succeeded")
    assert storage.size(kept) is not None and storage.size(stale) is None
    with pytest.raises(Conflict, match="only a finished job can re-run"):
        call(sessions, workflow.rerun, storage, broker, job_id)


def test_rerun_cannot_skip_an_unfinished_stage(
    sessions: SessionFactory, storage: LocalStorage, job_id: uuid.UUID
) -> None:
    run_to_failure(sessions, storage, job_id, "sync")
    with pytest.raises(Conflict, match=r"stage sync of job .* has not succeeded"):
        call(sessions, workflow.rerun, storage, Broker(), job_id, "pose")
    assert statuses(sessions, job_id)["sync"] == "failed"  # nothing changed


def test_rerun_from_track_plans_chunks_again(
    sessions: SessionFactory, storage: LocalStorage, job_id: uuid.UUID
) -> None:
    run_to_failure(sessions, storage, job_id, "track/cam2/00000180-00000360")
    broker = Broker()
    new_params = {**PARAMS, "chunk_s": 12}
    assert call(sessions, workflow.rerun, storage, broker, job_id, "track", new_params) == "track"
    assert sorted(broker.take()) == [
        "clock",
        *(f"track/cam{c}/{a:08d}-{b:08d}" for c in (1, 2) for a, b in ((0, 360), (360, 600))),
    ]
    with sessions() as session:
        job = session.get_one(Job, job_id)
        assert job.params["chunk_s"] == 12
        assert next(s for s in job.stages if s.key == "probe").attempt == 1
        assert len([s for s in job.stages if s.name == "track"]) == 4


def test_first_incomplete_stage() -> None:
    probe = StereoProbe(width=640, height=320, fps=30.0, n_frames={1: 600, 2: 600})
    units = graph.plan(probe, ProcessParams.model_validate(PARAMS))

    def rows(**status: str) -> list[Stage]:
        """Rows of every unit of the stages named, with their status."""
        stages = [workflow.new_stage(u) for u in units if u.stage in status]
        for stage in stages:
            stage.status = status[stage.name]
        return stages

    def first(stages: list[Stage], written: set[str]) -> str | None:
        incomplete = workflow.first_incomplete(stages, written)
        return incomplete[0] if incomplete else None

    done = dict.fromkeys(STAGE_NAMES, "succeeded")
    everything = {name for u in units for name in graph.writes(u)}
    assert first(rows(probe="failed"), set()) == "probe"
    assert first(rows(probe="succeeded"), {PROBE_JSON}) == "track"
    assert first(rows(**done), everything) is None
    assert first(rows(**{**done, "link": "cancelled"}), everything) == "link"
    assert first(rows(**{k: v for k, v in done.items() if k != "refit"}), everything) == "refit"
    # Succeeded under an earlier release that did not write a file the report now reads.
    assert workflow.first_incomplete(rows(**done), everything - {REFIT_PAIRS_NPZ}) == (
        "refit",
        f"did not write {REFIT_PAIRS_NPZ}, which later stages read "
        "(it ran under an earlier release)",
    )


def test_rerun_of_an_earlier_release_starts_where_its_outputs_end(
    sessions: SessionFactory, storage: LocalStorage, job_id: uuid.UUID
) -> None:
    """A job whose refit stage wrote less than today's, or never ran, re-runs from refit."""
    run_to_failure(sessions, storage, job_id, None)
    with transaction(sessions) as session:
        session.execute(delete(Artifact).where(Artifact.name == REFIT_PAIRS_NPZ))
    with pytest.raises(Conflict, match=rf"stage refit of job .* did not write {REFIT_PAIRS_NPZ}"):
        call(sessions, workflow.rerun, storage, Broker(), job_id, "report")
    assert set(statuses(sessions, job_id).values()) == {"succeeded"}  # nothing changed

    broker = Broker()
    assert call(sessions, workflow.rerun, storage, broker, job_id) == "refit"
    assert sorted(broker.sent_keys()) == ["clock", "refit"]
    drive(sessions, storage, broker, job_id)
    assert statuses(sessions, job_id)["report"] == "succeeded"

    # A release before the refit stage existed: no row at all. It is planned on re-run.
    with transaction(sessions) as session:
        job = session.get_one(Job, job_id)
        refit = next(s for s in job.stages if s.key == "refit")
        job.stages.remove(refit)
        session.delete(refit)
    assert call(sessions, workflow.rerun, storage, broker, job_id) == "refit"
    assert sorted(broker.take()) == ["clock", "refit"]
    assert statuses(sessions, job_id)["refit"] == "queued"
