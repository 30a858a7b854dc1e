"""Celery tasks: one per pipeline stage, each a thin wrapper around `runner.execute`.

Every task takes ``(job_id, stage_key, token)``; start a worker with
``firefly3d worker`` (or ``celery -A services.worker.tasks worker``).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

from celery import Task
from celery.exceptions import TimeLimitExceeded
from celery.signals import task_received, worker_process_init, worker_ready, worker_shutdown

from pipeline.graph import STAGE_NAMES
from services.core.db import SessionFactory, make_engine, make_session_factory
from services.core.settings import get_settings
from services.core.storage import make_storage
from services.worker.celery_app import make_celery
from services.worker.dispatch import sender, task_name
from services.worker.heartbeat import Reservations, Sweeper
from services.worker.inputs import InputCache
from services.worker.runner import Runtime, execute, fail_stage

app = make_celery(get_settings())


@lru_cache(maxsize=1)
def runtime() -> Runtime:
    """This process's connections, created on first use (after the pool forks)."""
    settings = get_settings()
    return Runtime(
        settings=settings,
        sessions=make_session_factory(make_engine(settings.database_url)),
        storage=make_storage(settings),
        send=sender(app, settings.queue),
        cache=InputCache(settings.cache_dir, settings.cache_max_bytes),
    )


@worker_process_init.connect
def _fresh_connections(**_: Any) -> None:
    # A forked pool process must not share the parent's database connections.
    if runtime.cache_info().currsize:
        engine = runtime().sessions.kw["bind"]
        engine.dispose(close=False)
    runtime.cache_clear()


@lru_cache(maxsize=1)
def main_sessions() -> SessionFactory:
    """Database sessions of the worker's main process (sweeper, reservations)."""
    return make_session_factory(make_engine(get_settings().database_url, pool_size=2))


@lru_cache(maxsize=1)
def sweeper() -> Sweeper:
    """The main process's sweeper of stalled stages."""
    settings = get_settings()
    storage, send = make_storage(settings), sender(app, settings.queue)
    return Sweeper(settings, main_sessions(), storage, send)


@lru_cache(maxsize=1)
def reservations() -> Reservations:
    """Stages whose messages this worker holds but has not started."""
    return Reservations(main_sessions(), get_settings().heartbeat_interval_s)


@worker_ready.connect
def _start_sweeper(**_: Any) -> None:
    reservations().start()
    sweeper().start()


@task_received.connect
def _reserved(request: Any, **_: Any) -> None:
    # The message is this worker's from now on; if the worker dies before it starts
    # the task, the stage's heartbeat stops and the sweeper queues it again.
    if len(request.args) == 3:
        reservations().add(request.args[2])


@worker_shutdown.connect
def _stop_sweeper(**_: Any) -> None:
    if sweeper.cache_info().currsize:
        sweeper().stop()


class StageTask(Task):
    """Records the hard time limit, which kills the task before it can record anything."""

    def on_failure(self, exc: Exception, task_id: str, args: Any, kwargs: Any, einfo: Any) -> None:
        if isinstance(exc, TimeLimitExceeded) and len(args) == 3:
            job_id, key, token = args
            limit = runtime().settings.task_time_limit_s
            fail_stage(runtime(), job_id, key, token, f"killed at the hard time limit of {limit} s")


def _define(stage: str) -> Task:
    def run_stage(self: Task, job_id: str, key: str, token: str) -> None:
        execute(self, runtime(), job_id, key, token)

    run_stage.__name__ = run_stage.__qualname__ = f"{stage}_stage"
    run_stage.__doc__ = f"The {stage} stage of a job."
    return app.task(name=task_name(stage), bind=True, base=StageTask)(run_stage)


TASKS = {stage: _define(stage) for stage in STAGE_NAMES}
