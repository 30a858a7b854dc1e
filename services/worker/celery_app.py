"""The Celery application and its reliability settings.

Why each setting (the broker is Redis; PostgreSQL holds the truth, see
`services.domain.workflow`):

* ``task_acks_late``: a message is acknowledged when its task *ends*, so a worker that
  dies mid-task (SIGKILL, OOM, lost machine) leaves it to be delivered again. Stages
  are idempotent (deterministic output keys, token-checked stage rows), so running one
  twice is safe.
* ``task_reject_on_worker_lost``: when only a pool process dies, requeue its message at
  once instead of acknowledging it as failed.
* Bounded deliveries: Redis does not count redeliveries, so each stage row counts its
  own (``stages.deliveries``) and gives up after ``max_attempts`` with a readable error:
  a video that crashes the decoder must not crash workers forever.
* ``worker_prefetch_multiplier = 1``: a process reserves one message at a time. Stages
  run for minutes; prefetching would park work behind a busy process and strand more
  messages when a worker dies.
* Soft / hard time limits: the soft limit raises inside the task, which records a
  readable failure; the hard limit kills a stuck process.
* ``visibility_timeout`` above the hard time limit (checked by `Settings`): Redis
  redelivers an unacknowledged message after this long. Were it shorter, a healthy
  long task would be handed to a second worker while still running.
* Retries with exponential backoff happen only for transient storage and database
  errors (see `services.worker.runner`); a bad video fails at once.
* No result backend: task results are never read; stage rows are the state.
"""

from __future__ import annotations

from celery import Celery

from services.core.settings import Settings


def make_celery(settings: Settings) -> Celery:
    """A Celery app configured from `settings` (the API uses it only to send tasks)."""
    app = Celery("firefly3d", broker=settings.broker_url, set_as_current=False)
    app.conf.update(
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        task_soft_time_limit=settings.task_soft_time_limit_s,
        task_time_limit=settings.task_time_limit_s,
        broker_transport_options={
            "visibility_timeout": settings.visibility_timeout_s,
            "global_keyprefix": settings.broker_key_prefix,
            # Look for messages abandoned by dead workers every interval (not every 10th).
            "unacked_restore_interval": settings.unacked_restore_interval_s,
            "unacked_restore_throttle": 1,
        },
        # Without this a worker that loses the broker keeps running its tasks while the
        # broker hands the same messages to another worker.
        worker_cancel_long_running_tasks_on_connection_loss=True,
        broker_connection_retry_on_startup=True,
        task_ignore_result=True,
        task_default_queue=settings.queue,
        task_serializer="json",
        accept_content=["json"],
        worker_send_task_events=False,
        enable_utc=True,
    )
    return app
