"""Property-based requests over the whole OpenAPI schema: no input makes the API fail (5xx)."""

from __future__ import annotations

from typing import Any

import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis.checks import not_a_server_error

from tests.services.conftest import Service
from tests.services.helpers import TEST_ADMIN_TOKEN, auth, make_team

#: Examples per operation: about a minute for the whole schema on two cores.
EXAMPLES = 80


def explore(operation: Any, token: str) -> None:
    """Send generated requests to one operation; fail on the first 5xx."""

    @given(case=operation.as_strategy())
    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    def no_server_error(case: schemathesis.Case) -> None:
        case.call_and_validate(headers=auth(token), checks=[not_a_server_error])

    no_server_error()


def test_no_server_errors(api_service: Service) -> None:
    team_token = make_team(api_service.sessions)
    schema = schemathesis.openapi.from_asgi("/openapi.json", api_service.app)
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 15
    for operation in operations:
        admin = operation.path.startswith("/api/v1/admin")
        explore(operation, TEST_ADMIN_TOKEN if admin else team_token)
