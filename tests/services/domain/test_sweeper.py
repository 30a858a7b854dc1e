"""The sweep of stalled stages and idle jobs, against the real database (broker: a list)."""

from __future__ import annotations

import datetime as dt
import time
import uuid
from pathlib import Path

from sqlalchemy import update
from sqlalchemy.orm import Session

from services.core.db import SessionFactory, transaction
from services.core.models import Job, Stage
from services.core.storage import Storage
from services.core.storage.local import LocalStorage
from services.domain import sweeper
from services.domain.repositories import jobs
from services.domain.states import now
from services.domain.sweeper import SWEEP_LOCK
from services.domain.workflow import Send
from tests.services.domain.test_workflow import Broker
from tests.services.helpers import queued_stage, stage_row

#: Far below the session's workers' stall limit (30 s): their sweepers leave these alone.
LIMIT_S = 5.0


def silent_for(sessions: SessionFactory, job_id: str, seconds: float) -> None:
    with transaction(sessions) as session:
        last = now() - dt.timedelta(seconds=seconds)
        session.execute(
            update(Stage)
            .where(Stage.job_id == uuid.UUID(job_id))
            .values(heartbeat_at=last, started_at=last)
        )


def sweep(session: Session, storage: Storage, send: Send) -> sweeper.SweepResult | None:
    """One sweep, waiting while a live worker of another test holds the lock.

    The session's workers sweep the same database every 2 s, holding the
    transaction-scoped lock for a moment: a sweep that meets it returns None.
    """
    deadline = time.monotonic() + 10.0
    result = sweeper.sweep(session, storage, send, LIMIT_S)
    while result is None and time.monotonic() < deadline:
        time.sleep(0.05)
        result = sweeper.sweep(session, storage, send, LIMIT_S)
    return result


def _of(job_id: str, stages: list[str]) -> list[str]:
    return [stage for stage in stages if stage.startswith(f"{job_id}/")]


def test_a_silent_running_stage_is_requeued_once(sessions: SessionFactory, tmp_path: Path) -> None:
    job_id, _, token = queued_stage(sessions, deliveries=1, status="running")
    silent_for(sessions, job_id, 2 * LIMIT_S)
    broker = Broker()
    with sessions() as session:
        result = sweep(session, LocalStorage(tmp_path), broker)
    # Only this job's stages: the database is shared with the other tests' jobs.
    assert result is not None and _of(job_id, result.requeued) == [f"{job_id}/sync"]
    stage = stage_row(sessions, job_id)
    assert stage.status == "queued" and stage.stalled_at is not None
    assert stage.queue_token != token and broker.sent[0].token == stage.queue_token
    assert stage.deliveries == 1  # kept: still bounded by max_attempts
    assert "stalled (no heartbeat for 10 s), re-queued at" in stage.warnings[-1]
    with sessions() as session:
        assert not jobs.beat(session, stage.id, token)  # the lost delivery is stale
        again = sweep(session, LocalStorage(tmp_path), broker)
    assert again is not None and _of(job_id, again.requeued) == []  # queued, not running


def test_a_beating_stage_is_left_alone(sessions: SessionFactory, tmp_path: Path) -> None:
    job_id, _, token = queued_stage(sessions, status="running")
    silent_for(sessions, job_id, 2 * LIMIT_S)
    with transaction(sessions) as session:
        assert jobs.beat(session, stage_row(sessions, job_id).id, token)
    with sessions() as session:
        result = sweep(session, LocalStorage(tmp_path), Broker())
    assert result is not None and f"{job_id}/sync" not in result.requeued
    assert stage_row(sessions, job_id).status == "running"


def test_one_sweep_at_a_time(sessions: SessionFactory, tmp_path: Path) -> None:
    with sessions() as holder, sessions() as other:
        assert jobs.try_advisory_lock(holder, SWEEP_LOCK)
        assert sweeper.sweep(other, LocalStorage(tmp_path), Broker(), LIMIT_S) is None
        holder.rollback()  # releases the lock
        assert sweep(other, LocalStorage(tmp_path), Broker()) is not None


def test_an_idle_active_job_is_advanced(sessions: SessionFactory, tmp_path: Path) -> None:
    """A job whose enqueue failed (stage back to pending) is queued again by the sweep."""
    job_id, _, _ = queued_stage(sessions, status="pending", name="probe")
    with transaction(sessions) as session:
        old = now() - dt.timedelta(seconds=2 * LIMIT_S)
        session.execute(update(Job).where(Job.id == uuid.UUID(job_id)).values(updated_at=old))
        session.execute(
            update(Stage).where(Stage.job_id == uuid.UUID(job_id)).values(queued_at=old)
        )
    broker = Broker()
    with sessions() as session:
        result = sweep(session, LocalStorage(tmp_path), broker)
    assert result is not None and uuid.UUID(job_id) in result.advanced
    assert [m.key for m in broker.sent if m.job_id == job_id] == ["probe"]
    assert stage_row(sessions, job_id).status == "queued"


def test_a_message_held_by_a_lost_worker_is_requeued(
    sessions: SessionFactory, tmp_path: Path
) -> None:
    """A queued stage whose message a worker took (and beat for) before dying."""
    held, _, held_token = queued_stage(sessions)
    waiting, _, _ = queued_stage(sessions)  # in the broker's queue: no heartbeat, no sweep
    with transaction(sessions) as session:
        assert jobs.beat_reserved(session, [held_token]) == {held_token}
    silent_for(sessions, held, 2 * LIMIT_S)
    with sessions() as session:
        result = sweep(session, LocalStorage(tmp_path), Broker())
    assert result is not None and f"{held}/sync" in result.requeued
    assert f"{waiting}/sync" not in result.requeued
    stage = stage_row(sessions, held)
    assert stage.status == "queued" and stage.queue_token != held_token
    assert stage.heartbeat_at is None  # until a worker takes the new message
