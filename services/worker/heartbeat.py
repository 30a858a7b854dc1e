"""Signs of life: a running stage's heartbeat, and the periodic sweep of silent ones.

`Heartbeat` runs beside a stage's body in the pool process and writes the stage's
``heartbeat_at`` every ``heartbeat_interval_s``, whatever the stage is doing (pose can
be silent for minutes; its progress callback is not called). When the process or the
whole machine dies, the writes stop and `services.domain.sweeper` re-queues the stage
after ``stall_limit_s``. A worker also holds messages it has not started yet (one per
pool process may wait while the process finishes its task); `Reservations`, in the
main process, beats those stages until they start, so that a message lost with its
worker is found the same way. `Sweeper` runs in every worker's main process and calls
the sweep every ``sweep_interval_s``; the sweep itself makes sure that only one runs
at a time across the cluster.
"""

from __future__ import annotations

import logging
import threading
from types import TracebackType

from sqlalchemy.exc import DBAPIError

from services.core.db import SessionFactory, transaction
from services.core.settings import Settings
from services.core.storage import Storage
from services.domain import sweeper
from services.domain.repositories import jobs
from services.domain.workflow import Send

log = logging.getLogger(__name__)


class Heartbeat:
    """Context manager: a thread beating for one claimed delivery while the body runs."""

    def __init__(self, sessions: SessionFactory, interval_s: float, stage_id: int, token: str):
        self.sessions, self.interval_s = sessions, interval_s
        self.stage_id, self.token = stage_id, token
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._run, name="heartbeat", daemon=True)

    def _run(self) -> None:
        while not self.stopped.wait(self.interval_s):
            try:
                with transaction(self.sessions) as session:
                    if not jobs.beat(session, self.stage_id, self.token):
                        return  # re-queued or finished elsewhere: the body will find out
            except DBAPIError:
                log.warning("could not write the heartbeat of stage %s", self.stage_id)

    def __enter__(self) -> Heartbeat:
        self.thread.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stopped.set()
        self.thread.join()


class Reservations:
    """The tokens of the stage messages this worker received but has not started.

    A daemon thread of the main process beats their stages at once when one arrives,
    then every interval, and forgets those that are no longer queued.
    """

    def __init__(self, sessions: SessionFactory, interval_s: float) -> None:
        self.sessions, self.interval_s = sessions, interval_s
        self.tokens: set[str] = set()
        self.lock = threading.Lock()
        self.wake = threading.Event()
        self.thread = threading.Thread(target=self._run, name="reservations", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def add(self, token: str) -> None:
        with self.lock:
            self.tokens.add(token)
        self.wake.set()

    def beat(self) -> None:
        with self.lock:
            held = set(self.tokens)
        if not held:
            return
        with transaction(self.sessions) as session:
            queued = jobs.beat_reserved(session, held)
        with self.lock:
            self.tokens -= held - queued

    def _run(self) -> None:
        while True:
            self.wake.wait(self.interval_s)
            self.wake.clear()
            try:
                self.beat()
            except DBAPIError:
                log.warning("could not write the heartbeat of reserved stages")


class Sweeper:
    """A daemon thread of a worker's main process: one sweep now, then every interval."""

    def __init__(
        self, settings: Settings, sessions: SessionFactory, storage: Storage, send: Send
    ) -> None:
        self.settings, self.sessions, self.storage, self.send = settings, sessions, storage, send
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._run, name="sweeper", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        self.stopped.set()
        self.thread.join(timeout=10)

    def sweep_once(self) -> sweeper.SweepResult | None:
        with self.sessions() as session:
            result = sweeper.sweep(session, self.storage, self.send, self.settings.stall_limit_s)
        if result and (result.requeued or result.advanced):
            log.warning(
                "sweep: re-queued stalled %s; advanced idle jobs %s", *vars(result).values()
            )
        return result

    def _run(self) -> None:
        while True:
            try:
                self.sweep_once()
            except Exception:  # the thread must outlive any one failure (database down, …)
                log.exception("sweep failed; trying again in %s s", self.settings.sweep_interval_s)
            if self.stopped.wait(self.settings.sweep_interval_s):
                return
