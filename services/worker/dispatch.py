"""Publishing stage messages as Celery tasks (used by the API and by workers)."""

from __future__ import annotations

from celery import Celery

from services.domain.workflow import Send, StageMessage


def task_name(stage: str) -> str:
    """Name of the Celery task that runs `stage`."""
    return f"firefly3d.stage.{stage}"


def sender(celery: Celery, queue: str) -> Send:
    """A `Send` that publishes stage messages as tasks on `queue`."""

    def send(messages: list[StageMessage]) -> None:
        for m in messages:
            celery.send_task(task_name(m.name), args=[m.job_id, m.key, m.token], queue=queue)

    return send
