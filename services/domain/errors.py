"""Domain errors: what went wrong, in the service's terms (the API maps them to HTTP).

Services and the workflow raise these and nothing HTTP-shaped; one exception handler
in `services.api.app` turns each kind into its status code.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence


class DomainError(Exception):
    """Base of the errors a client can cause or must be told about.

    ``headers`` are hints for the transport (e.g. where a resumable upload stands).
    """

    def __init__(self, message: str, headers: Mapping[str, str] | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.headers = dict(headers or {})


class NotFound(DomainError):
    """The thing does not exist, or the caller may not know that it does."""


class Conflict(DomainError):
    """The request does not fit the current state (e.g. submitting a running job)."""


class IllegalTransition(Conflict):
    """A job, stage or upload was asked to move to a state it cannot reach from its own."""


class Invalid(DomainError):
    """A value the caller sent is wrong; ``location`` names it (as in FastAPI's 422s)."""

    def __init__(
        self,
        location: Sequence[str | int],
        message: str,
        headers: Mapping[str, str] | None = None,
    ) -> None:
        super().__init__(message, headers)
        self.location = list(location)


class Unauthenticated(DomainError):
    """No credentials, or credentials that match nobody."""


class Forbidden(DomainError):
    """Valid credentials that do not allow this."""


class Unavailable(DomainError):
    """A service the request needs (broker, storage) is not answering: retry later."""


class TooManyRequests(DomainError):
    """The caller must slow down (e.g. too many failed authentications)."""
