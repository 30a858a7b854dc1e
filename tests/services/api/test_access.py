"""Authentication (401/403) and isolation between teams."""

from __future__ import annotations

import pytest

from tests.services.conftest import Service
from tests.services.helpers import TEST_ADMIN_TOKEN, auth, create_night, make_team

FILE = {"filename": "GS010001.mp4", "size": 1000, "sha256": "a" * 64}
FILES = [{**FILE, "camera": c, "chapter": 0} for c in (1, 2)]


@pytest.fixture(scope="module")
def two_teams(api_service: Service) -> tuple[str, str, dict, dict]:
    """Team A with a night and a job, and team B."""
    a, b = make_team(api_service.sessions), make_team(api_service.sessions)
    night = create_night(api_service.client, a)
    response = api_service.client.post(
        "/api/v1/jobs", json={"night_id": night["id"], "files": FILES}, headers=auth(a)
    )
    assert response.status_code == 201, response.text
    return a, b, night, response.json()


@pytest.mark.parametrize(
    ("method", "path"),
    [
        ("GET", "/api/v1/nights"),
        ("POST", "/api/v1/nights"),
        ("POST", "/api/v1/jobs"),
        ("GET", "/api/v1/jobs/00000000-0000-4000-8000-000000000000"),
        ("GET", "/api/v1/admin/jobs"),
    ],
)
@pytest.mark.parametrize("header", [None, "Bearer not-a-token", "Basic dXNlcjpwYXNz"])
def test_missing_or_wrong_token_is_401(
    api_service: Service, method: str, path: str, header: str | None
) -> None:
    headers = {"Authorization": header} if header else {}
    response = api_service.client.request(method, path, headers=headers, json={})
    assert response.status_code == 401
    assert response.headers["www-authenticate"] == "Bearer"
    assert "token" in response.json()["detail"]


def test_team_token_on_admin_routes_is_403(api_service: Service, two_teams: tuple) -> None:
    a, _, night, job = two_teams
    client = api_service.client
    for method, path in [
        ("GET", "/api/v1/admin/jobs"),
        ("POST", f"/api/v1/admin/jobs/{job['id']}/rerun"),
        ("POST", f"/api/v1/admin/nights/{night['id']}/rerun-failed"),
    ]:
        response = client.request(method, path, headers=auth(a), json={})
        assert response.status_code == 403, path
        assert response.json()["detail"] == "this route needs the admin token"


def test_admin_token_cannot_create_team_data(api_service: Service) -> None:
    response = api_service.client.get("/api/v1/nights", headers=auth(TEST_ADMIN_TOKEN))
    assert response.status_code == 403
    assert response.json()["detail"] == "this route needs a team token"


def test_other_team_sees_nothing(api_service: Service, two_teams: tuple) -> None:
    a, b, night, job = two_teams
    client = api_service.client
    job_url = f"/api/v1/jobs/{job['id']}"
    for method, path in [
        ("GET", f"/api/v1/nights/{night['id']}"),
        ("GET", job_url),
        ("POST", f"{job_url}/submit"),
        ("POST", f"{job_url}/cancel"),
        ("GET", f"{job_url}/artifacts"),
        ("GET", f"{job_url}/artifacts/trajectories.csv"),
        ("GET", f"{job_url}/files/1/0"),
        ("PUT", f"{job_url}/files/1/0"),
        ("POST", f"{job_url}/files/1/0/replace"),
    ]:
        body = {"content": b"x" * 10} if method == "PUT" else {"json": FILES[0]}
        response = client.request(method, path, headers=auth(b), **body)
        assert response.status_code == 404, (method, path, response.text)
    job_b = client.post(
        "/api/v1/jobs", json={"night_id": night["id"], "files": FILES}, headers=auth(b)
    )
    assert job_b.status_code == 404
    assert night["id"] not in [
        n["id"] for n in client.get("/api/v1/nights", headers=auth(b)).json()
    ]
    own = client.get("/api/v1/nights", headers=auth(a)).json()
    assert [n["id"] for n in own] == [night["id"]]
    assert [j["id"] for j in own[0]["jobs"]] == [job["id"]]


def test_admin_reads_any_job(api_service: Service, two_teams: tuple) -> None:
    _, _, _, job = two_teams
    response = api_service.client.get(f"/api/v1/jobs/{job['id']}", headers=auth(TEST_ADMIN_TOKEN))
    assert response.status_code == 200
    assert response.json()["id"] == job["id"]


def test_forged_download_link_is_refused(api_service: Service) -> None:
    response = api_service.client.get("/api/v1/downloads/eyJrZXkiOiAiam9icy94In0.forged")
    assert response.status_code == 403
    assert response.json()["detail"] == "this download link is invalid or has expired"
