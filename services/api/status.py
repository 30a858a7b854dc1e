"""The job status a page polls: one statement when nothing changed, and an ETag.

`StatusCache` keeps each job's rendered status (JSON bytes) with the version it was
rendered at (`services.domain.access.visible_job_version`). A poll reads the version
(one statement, autocommit: no BEGIN/ROLLBACK); if the client already has it, the
answer is 304; if this process has it, the cached bytes; otherwise the job is loaded
and rendered once for every client. Several API processes each keep their own cache;
the version check makes them all exact.
"""

from __future__ import annotations

import threading
import uuid
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

from sqlalchemy.orm import Session

from services.domain import access


@dataclass(frozen=True)
class Status:
    etag: str
    body: bytes | None  # None: the client's copy is current (304)


class StatusCache:
    """Rendered statuses of the most recently polled jobs (LRU)."""

    def __init__(self, max_jobs: int = 1024) -> None:
        self.max_jobs = max_jobs
        self.entries: OrderedDict[uuid.UUID, tuple[str, bytes]] = OrderedDict()
        self.lock = threading.Lock()  # requests run in the thread pool

    def read(
        self,
        session: Session,
        principal: access.Principal,
        job_id: uuid.UUID,
        if_none_match: str | None,
        render: Callable[[], bytes],
    ) -> Status:
        """The job's status for a caller who may see it (`NotFound` otherwise)."""
        if not session.in_transaction():  # auth came from the cache: no BEGIN/ROLLBACK
            session.connection(execution_options={"isolation_level": "AUTOCOMMIT"})
        version = access.visible_job_version(session, principal, job_id)
        etag = f'"{version}"'
        if if_none_match is not None and etag in if_none_match.split(", "):
            return Status(etag, None)
        with self.lock:
            cached = self.entries.get(job_id)
            if cached is not None and cached[0] == version:
                self.entries.move_to_end(job_id)
                return Status(etag, cached[1])
        body = render()
        with self.lock:
            self.entries[job_id] = (version, body)
            if len(self.entries) > self.max_jobs:
                self.entries.popitem(last=False)
        return Status(etag, body)
