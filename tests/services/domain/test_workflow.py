"""The job/stage state machine against the real database (the broker replaced by a list)."""

from __future__ import annotations

import datetime as dt
import uuid
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import pytest

from pipeline.artifacts import PROBE_JSON
from pipeline.graph import STAGE_NAMES
from pipeline.params import ProcessParams
from pipeline.probe import StereoProbe
from services.core.db import SessionFactory, transaction
from services.core.models import Artifact, InputFile, Job, Night, Stage, Team
from services.core.storage.local import LocalStorage
from services.domain import workflow
from services.domain.errors import Conflict
from services.domain.states import finish_job
from services.domain.workflow import EnqueueError, StageMessage

T = TypeVar("T")
PARAMS = {"chunk_s": 6, "tracking": {"block_s": 6}, "classifier": {"enabled": False}}


class Broker:
    """Records what `advance` sends."""

    def __init__(self) -> None:
        self.sent: list[StageMessage] = []

    def __call__(self, messages: list[StageMessage]) -> None:
        self.sent.extend(messages)

    def take(self) -> list[str]:
        keys, self.sent = [m.key for m in self.sent], []
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
    with transaction(sessions) as session:
        for stage in session.get_one(Job, job_id).stages:
            if stage.key in keys:
                stage.status, stage.attempt = status, stage.attempt + 1


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
        session.add(
            Artifact(
                job_id=job_id,
                stage_id=stage.id,
                name=name,
                storage_key=storage_key,
                size=path.stat().st_size,
                content_type="text/plain",
            )
        )
    return storage_key


def run_to_failure(
    sessions: SessionFactory, storage: LocalStorage, job_id: uuid.UUID, failing: str
) -> None:
    """Submit, succeed every stage before `failing`, fail it."""
    broker = Broker()
    call(sessions, workflow.submit, storage, broker, job_id)
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
        assert [a.name for a in job.artifacts] == ["work/sync.json"]
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


def test_default_rerun_stage() -> None:
    def rows(**status: str) -> list[Stage]:
        return [Stage(key=k, name=k.split("/")[0], status=v) for k, v in status.items()]

    assert workflow.default_rerun_stage(rows(probe="failed")) == "probe"
    assert workflow.default_rerun_stage(rows(probe="succeeded")) == "track"
    done = dict.fromkeys(STAGE_NAMES, "succeeded")
    assert workflow.default_rerun_stage(rows(**done)) is None
    assert workflow.default_rerun_stage(rows(**{**done, "link": "cancelled"})) == "link"
