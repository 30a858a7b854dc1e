"""Error classes of a stage delivery, run in-process (the worker tests cover real workers).

Transient storage errors are retried with backoff until ``max_attempts``; any other
error fails the stage and the job at once with its message.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from celery import Celery, Task
from celery.result import EagerResult

from pipeline.graph import StageResult
from services.core.db import SessionFactory
from services.core.settings import Settings
from services.core.storage import TransientStorageError
from services.core.storage.local import LocalStorage
from services.worker.inputs import InputCache
from services.worker.runner import Claim, Progress, Runtime, StageBody, execute
from tests.services.helpers import queued_stage, stage_row


def run_once(rt: Runtime, body: StageBody, job_id: str, key: str, token: str) -> EagerResult:
    """One delivery through a Celery task in eager mode (retries re-run in place)."""
    app = Celery("retries-test", set_as_current=False)
    app.conf.task_always_eager = True

    @app.task(bind=True)
    def stage(self: Task, job_id: str, key: str, token: str) -> None:
        execute(self, rt, job_id, key, token, body)

    return stage.apply(args=[job_id, key, token])


@pytest.fixture
def rt(sessions: SessionFactory, tmp_path: Path) -> Runtime:
    settings = Settings(max_attempts=3, retry_backoff_s=0, work_dir=tmp_path / "work")
    return Runtime(
        settings,
        sessions,
        LocalStorage(tmp_path / "store"),
        lambda m: None,
        InputCache(tmp_path / "c", 0),
    )


def flaky(failures: int) -> tuple[StageBody, list[int]]:
    calls: list[int] = []

    def body(ctx: Claim, workdir: Path, rt: Runtime, progress: Progress) -> StageResult:
        calls.append(ctx.attempt)
        if len(calls) <= failures:
            raise TransientStorageError("S3 SlowDown on jobs/x/work/probe.json")
        return StageResult(outputs=[], metrics={"ok": 1})

    return body, calls


def test_transient_error_is_retried(rt: Runtime, sessions: SessionFactory) -> None:
    job_id, key, token = queued_stage(sessions)
    body, calls = flaky(failures=2)
    run_once(rt, body, job_id, key, token)
    row = stage_row(sessions, job_id)
    assert calls == [1, 2, 3]
    assert (row.status, row.attempt, row.error, row.metrics) == ("succeeded", 3, None, {"ok": 1})


def test_retries_are_bounded(rt: Runtime, sessions: SessionFactory) -> None:
    job_id, key, token = queued_stage(sessions)
    body, calls = flaky(failures=10)
    result = run_once(rt, body, job_id, key, token)
    assert result.failed() and isinstance(result.result, TransientStorageError)
    row = stage_row(sessions, job_id)
    assert calls == [1, 2, 3]
    assert row.status == "failed"
    assert (
        row.error == "gave up after 3 attempts; last error: S3 SlowDown on jobs/x/work/probe.json"
    )


def test_other_errors_fail_at_once(rt: Runtime, sessions: SessionFactory) -> None:
    job_id, key, token = queued_stage(sessions)
    calls: list[int] = []

    def body(ctx: Claim, workdir: Path, rt: Runtime, progress: Progress) -> StageResult:
        calls.append(ctx.attempt)
        raise ValueError("GS010001.mp4: the video stream has no frames (empty video)")

    run_once(rt, body, job_id, key, token)
    row = stage_row(sessions, job_id)
    assert calls == [1] and row.status == "failed"
    assert row.error == "GS010001.mp4: the video stream has no frames (empty video)"
