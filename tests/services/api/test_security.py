"""Tokens (expiry, revocation, rotation), failed-authentication limits, quotas, security
headers, offline API docs, atomic job creation and the status ETag."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import func, select

from services.core.models import Night
from tests.services.conftest import Service, make_settings
from tests.services.helpers import NIGHT, TEST_ADMIN_TOKEN, auth, create_night, make_team

ADMIN = auth(TEST_ADMIN_TOKEN)
FILES = [
    {"camera": 1, "chapter": 0, "filename": "GS010001.mp4", "size": 600},
    {"camera": 2, "chapter": 0, "filename": "GS010002.mp4", "size": 600},
]


@pytest.fixture(scope="module")
def strict(
    database_url: str, broker_prefix: str, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Service]:
    """An API with quotas, a short auth cache and a low failed-authentication limit."""
    settings = make_settings(
        database_url,
        broker_prefix,
        tmp_path_factory.mktemp("strict"),
        backend="local",
        auth_cache_s=0.5,
        auth_failures_limit=3,
        quota_job_bytes=1500,
        quota_night_bytes=2000,
        quota_active_jobs=1,
    )
    service = Service(settings)
    yield service
    service.client.close()


def test_tokens_are_issued_revoked_rotated_and_expire(strict: Service) -> None:
    client = strict.client
    created = client.post("/api/v1/admin/teams", json={"name": "Token crew"}, headers=ADMIN)
    assert created.status_code == 201, created.text
    first = created.json()
    laptop = client.post(
        f"/api/v1/admin/teams/{first['team_id']}/tokens",
        json={"label": "field laptop", "expires_in_days": 0.00001},  # about a second
        headers=ADMIN,
    ).json()
    assert laptop["token"]["state"].startswith("valid until")
    for issued in (first, laptop):
        assert client.get("/api/v1/nights", headers=auth(issued["secret"])).status_code == 200
    teams = client.get("/api/v1/admin/teams", headers=ADMIN).json()
    listed = next(t for t in teams if t["name"] == "Token crew")
    assert {t["label"] for t in listed["tokens"]} == {"initial", "field laptop"}
    assert all(first["secret"] not in str(t) for t in listed["tokens"])  # never shown again

    time.sleep(1.0)  # the laptop's token expired
    expired = client.get("/api/v1/nights", headers=auth(laptop["secret"]))
    assert expired.status_code == 401
    revoked = client.post(f"/api/v1/admin/tokens/{first['token']['id']}/revoke", headers=ADMIN)
    assert revoked.json()["state"].startswith("revoked")
    time.sleep(0.6)  # past the auth cache
    assert client.get("/api/v1/nights", headers=auth(first["secret"])).status_code == 401

    rotated = client.post(
        f"/api/v1/admin/teams/{first['team_id']}/rotate", json={}, headers=ADMIN
    ).json()
    assert client.get("/api/v1/nights", headers=auth(rotated["secret"])).status_code == 200


def test_failed_authentications_are_limited(strict: Service) -> None:
    client = strict.client
    good = make_team(strict.sessions)
    strict.app.state.auth_limiter.failures.clear()  # the test client has one address
    for _ in range(3):
        assert client.get("/api/v1/nights", headers=auth("ff3d_guess")).status_code == 401
    limited = client.get("/api/v1/nights", headers=auth(good))  # even a valid one: no oracle
    assert limited.status_code == 429 and int(limited.headers["retry-after"]) > 0
    strict.app.state.auth_limiter.failures.clear()


def test_quotas(strict: Service) -> None:
    client = strict.client
    token = make_team(strict.sessions)
    night = create_night(client, token)
    big = [{**f, "size": 800} for f in FILES]
    too_big = client.post(
        "/api/v1/jobs", json={"night_id": night["id"], "files": big}, headers=auth(token)
    )
    assert too_big.status_code == 422
    assert "at most 1500 bytes" in too_big.json()["detail"][0]["msg"]
    for expected in (201, 422):  # 1200 bytes fit the night's 2000, twice do not
        response = client.post(
            "/api/v1/jobs", json={"night_id": night["id"], "files": FILES}, headers=auth(token)
        )
        assert response.status_code == expected, response.text
    assert "quota of 2000 bytes" in response.json()["detail"][0]["msg"]


def test_a_refused_job_leaves_no_night(api_service: Service) -> None:
    client = api_service.client
    token = make_team(api_service.sessions)

    def nights() -> int:
        with api_service.sessions() as session:
            return int(session.scalar(select(func.count()).select_from(Night)) or 0)

    before = nights()
    body = {"night": NIGHT, "files": FILES, "params": {"sync": {"window_s": -1}}}
    refused = client.post("/api/v1/jobs", json=body, headers=auth(token))
    assert refused.status_code == 422 and "sync.window_s" in refused.text
    assert nights() == before
    created = client.post("/api/v1/jobs", json={**body, "params": None}, headers=auth(token))
    assert created.status_code == 201, created.text
    assert nights() == before + 1
    both = {**body, "params": None, "night_id": created.json()["night_id"]}
    assert client.post("/api/v1/jobs", json=both, headers=auth(token)).status_code == 422


def test_status_answers_304_until_the_job_changes(api_service: Service) -> None:
    client = api_service.client
    token = make_team(api_service.sessions)
    job = client.post(
        "/api/v1/jobs", json={"night": NIGHT, "files": FILES}, headers=auth(token)
    ).json()
    url = f"/api/v1/jobs/{job['id']}"
    first = client.get(url, headers=auth(token))
    etag = first.headers["etag"]
    same = client.get(url, headers={**auth(token), "If-None-Match": etag})
    assert same.status_code == 304 and same.content == b""
    other = make_team(api_service.sessions)  # the ETag does not bypass access control
    assert client.get(url, headers={**auth(other), "If-None-Match": etag}).status_code == 404
    assert client.post(f"{url}/cancel", headers=auth(token)).status_code == 200
    changed = client.get(url, headers={**auth(token), "If-None-Match": etag})
    assert changed.status_code == 200 and changed.headers["etag"] != etag
    assert changed.json()["status"] == "cancelled"


def test_every_page_has_security_headers_and_docs_are_offline(api_service: Service) -> None:
    client = api_service.client
    for path in ("/", "/admin", "/docs", "/redoc", "/healthz", "/api/v1/nights"):
        headers = client.get(path).headers
        csp = headers["content-security-policy"]
        assert "script-src 'self' 'wasm-unsafe-eval'" in csp, path
        assert "frame-ancestors 'none'" in csp and "unsafe-inline" not in csp.split("style")[0]
        assert headers["x-content-type-options"] == "nosniff"
        assert headers["x-frame-options"] == "DENY"
        assert headers["referrer-policy"] == "no-referrer"
    for page in ("/docs", "/redoc", "/", "/admin", f"/jobs/{'0' * 8}-0000-0000-0000-{'0' * 12}"):
        html = client.get(page).text
        assert "<script>" not in html and "cdn" not in html.lower(), page
    for asset in ("swagger-ui-bundle.js", "swagger-ui.css", "redoc.standalone.js"):
        assert client.get(f"/static/apidocs/{asset}").status_code == 200


def test_api_refuses_to_start_without_the_shared_secret(tmp_path: Path) -> None:
    from services.api.app import create_app

    settings = make_settings("postgresql+psycopg://x@127.0.0.1/x", "p", tmp_path, backend="local")
    with pytest.raises(ValueError, match="FIREFLY3D_SECRET_KEY is not set"):
        create_app(settings.model_copy(update={"secret_key": None}))
