"""Finding stalled work: stages whose worker died, jobs whose messages were lost.

A worker heartbeats each running stage in PostgreSQL, and each stage whose message it
holds but has not started yet (`services.worker.heartbeat`). When a whole worker
machine dies, its broker messages come back only after Redis's visibility timeout
(above the longest task: about an hour), so the stage would sit ``running`` (or
``queued``) that long. `sweep` re-queues every such stage whose heartbeat is older
than ``stall_limit_s`` as a new attempt with a new token (the old message, if it is
ever delivered again, is then stale and ignored), and advances active jobs that have
had nothing queued or running for as long (an enqueue that failed). One sweep runs at a time across
the cluster (a PostgreSQL advisory lock); every worker tries periodically.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass

from sqlalchemy.orm import Session

from services.core.models import StageStatus
from services.core.storage import Storage
from services.domain import states, workflow
from services.domain.repositories import jobs
from services.domain.workflow import Send, StageMessage

#: Advisory lock key of the sweep (any constant unique to it).
SWEEP_LOCK = 0x0F1E_F13D


@dataclass(frozen=True)
class SweepResult:
    """What one sweep did (None: another sweeper held the lock)."""

    requeued: list[str]
    advanced: list[uuid.UUID]


def sweep(
    session: Session, storage: Storage, send: Send, stall_limit_s: float
) -> SweepResult | None:
    """Re-queue stalled stages and advance idle active jobs (commits; see the module)."""
    if not jobs.try_advisory_lock(session, SWEEP_LOCK):
        session.rollback()
        return None
    messages = []
    for job_id in sorted({job_id for job_id, _, _ in jobs.stalled(session, stall_limit_s)}):
        job = workflow.locked(session, job_id)
        silent = {stage_id: s for _, stage_id, s in jobs.stalled(session, stall_limit_s, job_id)}
        for stage in job.stages:
            if stage.id in silent and stage.status in (StageStatus.RUNNING, StageStatus.QUEUED):
                token = states.requeue_stalled(stage, silent[stage.id])
                messages.append(StageMessage(str(job.id), stage.key, stage.name, token))
    session.commit()
    workflow.send_or_revert(session, send, messages)
    idle = jobs.idle_active(session, stall_limit_s)
    session.commit()
    for job_id in idle:
        workflow.advance(session, storage, send, job_id)
    return SweepResult([f"{m.job_id}/{m.key}" for m in messages], idle)
