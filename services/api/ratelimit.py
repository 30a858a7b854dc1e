"""A limit on failed authentications per client address (one API process's view).

Tokens carry 256 random bits, so guessing one is hopeless anyway; the limit keeps a
misconfigured client or a scanner from filling the logs and the database with failed
lookups. While a client is over the limit every request with a token answers 429,
valid or not, so that the answer tells a guesser nothing. Each API process counts on
its own: with N processes a client gets up to N × the limit (documented).
"""

from __future__ import annotations

import time
from collections import deque

from services.domain.errors import TooManyRequests


class FailureLimiter:
    """At most `limit` failures per client in any `window_s` seconds."""

    def __init__(self, limit: int, window_s: float, max_clients: int = 10_000) -> None:
        self.limit, self.window_s, self.max_clients = limit, window_s, max_clients
        self.failures: dict[str, deque[float]] = {}

    def _recent(self, client: str, now: float) -> deque[float]:
        times = self.failures.get(client, deque())
        while times and times[0] <= now - self.window_s:
            times.popleft()
        return times

    def check(self, client: str) -> None:
        """Raise `TooManyRequests` while `client` is over the limit."""
        now = time.monotonic()
        times = self._recent(client, now)
        if len(times) >= self.limit:
            retry = max(1, round(times[0] + self.window_s - now))
            raise TooManyRequests(
                f"too many failed authentications from {client}: try again in {retry} s",
                headers={"Retry-After": str(retry)},
            )

    def failed(self, client: str) -> None:
        now = time.monotonic()
        if len(self.failures) >= self.max_clients:
            self.failures = {c: t for c, t in self.failures.items() if self._recent(c, now)}
        times = self._recent(client, now)
        times.append(now)
        self.failures[client] = times
