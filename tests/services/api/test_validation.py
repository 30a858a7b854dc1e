"""Bad metadata is refused with 422 and a message that says what is wrong."""

from __future__ import annotations

from typing import Any

import pytest

from tests.services.conftest import Service
from tests.services.helpers import NIGHT, auth, create_night, make_team

GOOD_FILE = {"filename": "GS010001.mp4", "size": 1000, "sha256": "ab" * 32}


def messages(response: Any) -> str:
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    return " | ".join(f"{'.'.join(map(str, d['loc']))}: {d['msg']}" for d in detail)


@pytest.fixture(scope="module")
def team(api_service: Service) -> str:
    return make_team(api_service.sessions)


@pytest.fixture(scope="module")
def night_id(api_service: Service, team: str) -> str:
    return str(create_night(api_service.client, team)["id"])


@pytest.mark.parametrize(
    ("changes", "expected"),
    [
        ({"separation_m": -1.5}, "separation_m: Input should be greater than 0"),
        ({"separation_m": 0}, "separation_m: Input should be greater than 0"),
        ({"separation_m": 1500}, "separation_m: Input should be less than or equal to 100"),
        ({"separation_m": "1,5"}, "separation_m: Input should be a valid number"),
        ({"latitude": 91}, "latitude: Input should be less than or equal to 90"),
        ({"height_m": -2}, "height_m: Input should be greater than or equal to 0"),
        ({"date": "1999-12-31"}, "date: Value error, date must be between 2000-01-01"),
        ({"site": ""}, "site: String should have at least 1 character"),
        ({"site": "a\x00b"}, "site: Value error, must not contain control characters"),
        ({"notes": "x" * 5001}, "notes: String should have at most 5000 characters"),
        ({"camera_count": 2}, "camera_count: Extra inputs are not permitted"),
        ({"time_zone": "Mars/Olympus"}, "time_zone: Value error, unknown time zone 'Mars/Olympus'"),
        ({"time_zone": None}, "start time 2026-06-12T21:30:00 has no UTC offset"),
        ({"camera_clock": "gps"}, "camera_clock: Input should be 'local' or 'utc'"),
    ],
)
def test_bad_night(api_service: Service, team: str, changes: dict, expected: str) -> None:
    response = api_service.client.post(
        "/api/v1/nights", json={**NIGHT, **changes}, headers=auth(team)
    )
    assert expected in messages(response)


def test_nan_separation_is_refused(api_service: Service, team: str) -> None:
    body = '{"site": "x", "date": "2026-06-01", "separation_m": NaN}'
    response = api_service.client.post(
        "/api/v1/nights", content=body, headers={**auth(team), "Content-Type": "application/json"}
    )
    assert response.status_code == 422


def files(*specs: tuple[int, int], **changes: Any) -> list[dict[str, Any]]:
    return [{**GOOD_FILE, "camera": c, "chapter": ch, **changes} for c, ch in specs]


@pytest.mark.parametrize(
    ("declared", "expected"),
    [
        (files((1, 0), (3, 0)), "unknown camera 3: cameras are 1 and 2"),
        (files((1, 0), (1, 1)), "camera 2 has no chapter files"),
        (
            files((1, 0), (1, 2), (2, 0)),
            "camera 1: chapters must be numbered 0, 1, 2, … without gaps or repeats; got 0, 2",
        ),
        (files((1, 0), (1, 0), (2, 0)), "without gaps or repeats; got 0, 0"),
        (files((1, 1), (2, 0)), "camera 1: chapters must be numbered 0, 1, 2"),
        (files((1, 0), (2, 0), size=0), "size: Input should be greater than 0"),
        (files((1, 0), (2, 0), sha256="xyz"), "sha256 must be 64 hexadecimal digits"),
        (files((1, 0), (2, -1)), "chapter: Input should be greater than or equal to 0"),
    ],
)
def test_bad_files(
    api_service: Service, team: str, night_id: str, declared: list, expected: str
) -> None:
    body = {"night_id": night_id, "files": declared}
    assert expected in messages(
        api_service.client.post("/api/v1/jobs", json=body, headers=auth(team))
    )


@pytest.mark.parametrize(
    "name",
    [
        "../../etc/passwd",
        "videos/GS010001.mp4",
        "..\\GS010001.mp4",
        "..",
        ".",
        "GS01\x00.mp4",
        "",
        "evil\u202egpj.mp4",  # right-to-left override: reads as "evilmp4.jpg"
        "GS01\u2066.mp4",
        "GS01\u200b.mp4",  # zero-width space: not printable
    ],
)
def test_path_traversal_file_names(
    api_service: Service, team: str, night_id: str, name: str
) -> None:
    body = {"night_id": night_id, "files": files((1, 0), (2, 0), filename=name)}
    text = messages(api_service.client.post("/api/v1/jobs", json=body, headers=auth(team)))
    assert "filename" in text
    assert "must be a plain name" in text or "at least 1 character" in text


def test_oversized_declared_size(api_service: Service, team: str, night_id: str) -> None:
    limit = api_service.settings.max_file_bytes
    body = {"night_id": night_id, "files": files((1, 0), (2, 0), size=limit + 1)}
    text = messages(api_service.client.post("/api/v1/jobs", json=body, headers=auth(team)))
    assert text == (
        f"body.files.0.size: GS010001.mp4: declared size {limit + 1} bytes exceeds the limit "
        f"of {limit} bytes per file"
    )


@pytest.mark.parametrize(
    ("params", "expected"),
    [
        ({"chunk_s": -1}, "chunk_s: Input should be greater than 0"),
        (
            {"tracking": {"threshold": 2000}},
            "tracking.threshold: Input should be less than or equal to 1000",
        ),
        ({"no_such_stage": {}}, "no_such_stage: Extra inputs are not permitted"),
    ],
)
def test_bad_parameter_overrides(
    api_service: Service, team: str, night_id: str, params: dict, expected: str
) -> None:
    body = {"night_id": night_id, "files": files((1, 0), (2, 0)), "params": params}
    text = messages(api_service.client.post("/api/v1/jobs", json=body, headers=auth(team)))
    assert text.startswith("body.params: invalid parameters: ") and expected in text


def test_unknown_camera_in_url(api_service: Service, team: str, night_id: str) -> None:
    body = {"night_id": night_id, "files": files((1, 0), (2, 0))}
    job = api_service.client.post("/api/v1/jobs", json=body, headers=auth(team)).json()
    response = api_service.client.get(f"/api/v1/jobs/{job['id']}/files/3/0", headers=auth(team))
    assert "camera: Input should be less than or equal to 2" in messages(response)
    missing = api_service.client.get(f"/api/v1/jobs/{job['id']}/files/2/5", headers=auth(team))
    assert missing.status_code == 404
    assert missing.json()["detail"] == f"job {job['id']} has no file for camera 2 chapter 5"
