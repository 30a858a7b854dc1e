"""Uploads: streamed pieces to local storage, presigned multipart parts to S3; both resume."""

from __future__ import annotations

import base64
import hashlib
import os
from pathlib import Path
from typing import Any

import httpx
import pytest

from services.core.storage import MAX_PARTS, part_size_for
from tests.services.conftest import Service
from tests.services.helpers import (
    auth,
    create_job,
    create_night,
    declare,
    make_team,
    upload_stream,
)

MiB = 1 << 20


@pytest.fixture(scope="module")
def videos(tmp_path_factory: pytest.TempPathFactory) -> dict[int, list[Path]]:
    """Random bytes standing in for videos (uploads do not look inside): 12 MiB + 1 MiB."""
    out = tmp_path_factory.mktemp("uploads")
    files = {1: out / "GS010001.mp4", 2: out / "GS010002.mp4"}
    files[1].write_bytes(os.urandom(12 * MiB + 123))
    files[2].write_bytes(os.urandom(1 * MiB))
    return {camera: [path] for camera, path in files.items()}


def new_job(service: Service, videos: dict[int, list[Path]]) -> tuple[str, dict[str, Any]]:
    token = make_team(service.sessions)
    return token, create_job(service.client, token, videos)


def test_part_size_fits_s3_limits() -> None:
    assert part_size_for(1, 8 * MiB) == 8 * MiB
    assert part_size_for(100 * MiB * MAX_PARTS, 8 * MiB) == 100 * MiB
    big = 48 * (1 << 40)  # 48 TiB: parts just under S3's 5 GiB maximum
    assert part_size_for(big, 8 * MiB) * MAX_PARTS >= big


def test_stream_upload_in_pieces_resumes(api_service: Service, videos: dict) -> None:
    client = api_service.client
    token, job = new_job(api_service, videos)
    file = job["files"][0]
    url, data = file["upload_url"], videos[1][0].read_bytes()
    assert file["method"] == "stream" and file["part_count"] == 3  # 5 MiB pieces

    first = client.put(
        url,
        content=data[: 5 * MiB],
        headers={**auth(token), "Content-Range": f"bytes 0-{5 * MiB - 1}/{len(data)}"},
    )
    assert first.status_code == 200, first.text
    assert first.json()["received_bytes"] == 5 * MiB
    assert first.json()["upload_state"] == "uploading"
    # A client that lost track resends from the wrong place: told where to resume.
    wrong = client.put(
        url, content=data[:100], headers={**auth(token), "Content-Range": f"bytes 0-99/{len(data)}"}
    )
    assert wrong.status_code == 409
    assert wrong.headers["upload-offset"] == str(5 * MiB)
    status = client.get(url, headers=auth(token)).json()
    assert status["received_bytes"] == 5 * MiB

    rest = upload_stream(client, token, url, videos[1][0], 5 * MiB, offset=5 * MiB)
    assert rest["upload_state"] == "uploaded" and rest["received_bytes"] == len(data)
    key = f"jobs/{job['id']}/input/cam1/00.mp4"
    assert b"".join(api_service.storage.iter_bytes(key)) == data
    again = client.put(url, content=data, headers=auth(token))
    assert again.status_code == 409 and "already uploaded" in again.json()["detail"]


def part_digests(data: bytes, size: int) -> list[bytes]:
    return [hashlib.sha256(data[i : i + size]).digest() for i in range(0, len(data), size)]


def test_whole_file_put_starts_over(api_service: Service, videos: dict) -> None:
    client = api_service.client
    token, job = new_job(api_service, videos)
    url, data = job["files"][0]["upload_url"], videos[1][0].read_bytes()
    headers = {**auth(token), "Content-Range": f"bytes 0-{5 * MiB - 1}/{len(data)}"}
    assert client.put(url, content=b"\0" * 5 * MiB, headers=headers).status_code == 200
    done = client.put(url, content=data, headers=auth(token))
    assert done.status_code == 200, done.text
    assert done.json()["upload_state"] == "uploaded"
    composite = hashlib.sha256(b"".join(part_digests(data, 5 * MiB))).hexdigest()
    assert done.json()["checksum"] == composite  # S3's checksum of the part checksums


def test_short_body_is_an_error_that_keeps_whole_parts(api_service: Service, videos: dict) -> None:
    client = api_service.client
    token, job = new_job(api_service, videos)
    url, data = job["files"][0]["upload_url"], videos[1][0].read_bytes()
    short = client.put(url, content=data[: 7 * MiB], headers=auth(token))
    assert short.status_code == 422
    assert short.headers["upload-offset"] == str(5 * MiB)
    assert "body ended after 7340032 of 12583035 bytes" in short.json()["detail"][0]["msg"]
    status = client.get(url, headers=auth(token)).json()
    assert (status["received_bytes"], status["uploaded_parts"]) == (5 * MiB, [1])
    rest = upload_stream(client, token, url, videos[1][0], 5 * MiB, offset=5 * MiB)
    assert rest["upload_state"] == "uploaded"
    key = f"jobs/{job['id']}/input/cam1/00.mp4"
    assert b"".join(api_service.storage.iter_bytes(key)) == data


def test_stream_part_checksum_is_checked(api_service: Service, videos: dict) -> None:
    client = api_service.client
    token = make_team(api_service.sessions)
    declared = [{**f, "sha256": None} for f in declare(videos)]  # as the page declares
    night = create_night(client, token)
    job = client.post(
        "/api/v1/jobs", json={"night_id": night["id"], "files": declared}, headers=auth(token)
    ).json()
    url, data = job["files"][0]["upload_url"], videos[1][0].read_bytes()
    digests = part_digests(data, 5 * MiB)
    piece = {**auth(token), "Content-Range": f"bytes 0-{5 * MiB - 1}/{len(data)}"}
    wrong = {**piece, "x-amz-checksum-sha256": base64.b64encode(digests[1]).decode()}
    refused = client.put(url, content=data[: 5 * MiB], headers=wrong)
    assert refused.status_code == 422
    assert refused.json()["detail"][0]["msg"].startswith("part 1 does not match its SHA-256")
    assert client.get(url, headers=auth(token)).json()["received_bytes"] == 0
    for number, start in enumerate(range(0, len(data), 5 * MiB)):
        end = min(start + 5 * MiB, len(data))
        headers = {
            **auth(token),
            "Content-Range": f"bytes {start}-{end - 1}/{len(data)}",
            "x-amz-checksum-sha256": base64.b64encode(digests[number]).decode(),
        }
        done = client.put(url, content=data[start:end], headers=headers)
        assert done.status_code == 200, done.text
    assert done.json()["checksum"] == hashlib.sha256(b"".join(digests)).hexdigest()


def test_stream_upload_refuses_wrong_checksum_and_extra_bytes(
    api_service: Service, videos: dict
) -> None:
    client = api_service.client
    token, job = new_job(api_service, videos)
    file = job["files"][1]
    data = bytearray(videos[2][0].read_bytes())
    data[-1] ^= 0xFF
    bad = client.put(file["upload_url"], content=bytes(data), headers=auth(token))
    assert bad.status_code == 422
    message = bad.json()["detail"][0]["msg"]
    assert message.startswith("GS010002.mp4: SHA-256 of the received file is ")
    assert hashlib.sha256(data).hexdigest() in message and file["sha256"] in message
    status = client.get(file["upload_url"], headers=auth(token)).json()
    assert status["upload_state"] == "pending" and status["received_bytes"] == 0

    longer = client.put(file["upload_url"], content=bytes(data) + b"x", headers=auth(token))
    assert longer.status_code == 422
    assert "longer than the" in longer.json()["detail"][0]["msg"]
    assert client.get(file["upload_url"], headers=auth(token)).json()["received_bytes"] == 0


def test_multipart_routes_refused_on_local_storage(api_service: Service, videos: dict) -> None:
    token, job = new_job(api_service, videos)
    url = job["files"][0]["upload_url"]
    response = api_service.client.post(
        f"{url}/parts", json={"part_numbers": [1]}, headers=auth(token)
    )
    assert response.status_code == 409
    assert response.json()["detail"] == "this server takes stream uploads: PUT the file to this URL"


def test_submit_before_upload_is_refused(api_service: Service, videos: dict) -> None:
    token, job = new_job(api_service, videos)
    response = api_service.client.post(f"/api/v1/jobs/{job['id']}/submit", headers=auth(token))
    assert response.status_code == 409
    assert response.json()["detail"] == (
        "not uploaded yet: camera 1 chapter 0 (GS010001.mp4), camera 2 chapter 0 (GS010002.mp4)"
    )


def put_parts(client: Any, token: str, url: str, data: bytes, numbers: list[int]) -> dict:
    signed = client.post(f"{url}/parts", json={"part_numbers": numbers}, headers=auth(token))
    assert signed.status_code == 200, signed.text
    size = signed.json()["part_size"]
    for part in signed.json()["parts"]:
        start = (part["number"] - 1) * size
        assert httpx.put(part["url"], content=data[start : start + size]).status_code == 200
    return signed.json()


def test_multipart_upload_resumes_and_completes(s3_api_service: Service, videos: dict) -> None:
    client = s3_api_service.client
    token, job = new_job(s3_api_service, videos)
    file = job["files"][0]
    url, data = file["upload_url"], videos[1][0].read_bytes()
    assert file["method"] == "s3-multipart" and file["part_count"] == 3

    signed = put_parts(client, token, url, data, [1, 3])
    assert signed["part_count"] == 3 and [p["number"] for p in signed["parts"]] == [1, 3]
    status = client.get(url, headers=auth(token)).json()  # what a reloaded page asks
    assert status["uploaded_parts"] == [1, 3]
    assert status["received_bytes"] == 5 * MiB + (len(data) - 10 * MiB)
    early = client.post(f"{url}/complete", headers=auth(token))
    assert early.status_code == 409 and early.json()["detail"] == "1 of 3 parts are missing: 2"

    put_parts(client, token, url, data, [2])
    done = client.post(f"{url}/complete", headers=auth(token))
    assert done.status_code == 200, done.text
    assert done.json()["upload_state"] == "uploaded"
    key = f"jobs/{job['id']}/input/cam1/00.mp4"
    assert b"".join(s3_api_service.storage.iter_bytes(key)) == data
    beyond = client.post(f"{url}/parts", json={"part_numbers": [1]}, headers=auth(token))
    assert beyond.status_code == 409


def test_multipart_parts_carry_signed_checksums(s3_api_service: Service, videos: dict) -> None:
    client = s3_api_service.client
    token = make_team(s3_api_service.sessions)
    night = create_night(client, token)
    declared = [{**f, "sha256": None} for f in declare(videos)]
    job = client.post(
        "/api/v1/jobs", json={"night_id": night["id"], "files": declared}, headers=auth(token)
    ).json()
    unchecked = job["files"][1]  # neither a declared SHA-256 nor part checksums
    put_parts(client, token, unchecked["upload_url"], videos[2][0].read_bytes(), [1])
    refused = client.post(f"{unchecked['upload_url']}/complete", headers=auth(token))
    assert refused.status_code == 422 and "no checksum" in refused.json()["detail"][0]["msg"]

    url, data = job["files"][0]["upload_url"], videos[1][0].read_bytes()
    digests = part_digests(data, 5 * MiB)
    checksums = [base64.b64encode(d).decode() for d in digests]
    body = {"part_numbers": [1, 2, 3], "checksums_sha256": checksums}
    signed = client.post(f"{url}/parts", json=body, headers=auth(token))
    assert signed.status_code == 200, signed.text
    for part, checksum in zip(signed.json()["parts"], checksums, strict=True):
        assert "x-amz-checksum-sha256" in part["url"]  # signed: S3 refuses another body
        start = (part["number"] - 1) * 5 * MiB
        response = httpx.put(
            part["url"],
            content=data[start : start + 5 * MiB],
            headers={"x-amz-checksum-sha256": checksum},
        )
        assert response.status_code == 200
    unsigned = client.post(f"{url}/parts", json={"part_numbers": [1]}, headers=auth(token))
    assert unsigned.status_code == 422  # an upload with checksums needs them on every part
    done = client.post(f"{url}/complete", headers=auth(token))
    assert done.status_code == 200, done.text
    assert done.json()["checksum"] == hashlib.sha256(b"".join(digests)).hexdigest()


def test_multipart_part_of_wrong_size_is_refused(s3_api_service: Service, videos: dict) -> None:
    client = s3_api_service.client
    token, job = new_job(s3_api_service, videos)
    file = job["files"][1]  # one part of 1 MiB
    signed = client.post(
        f"{file['upload_url']}/parts", json={"part_numbers": [1]}, headers=auth(token)
    )
    assert httpx.put(signed.json()["parts"][0]["url"], content=b"short").status_code == 200
    response = client.post(f"{file['upload_url']}/complete", headers=auth(token))
    assert response.status_code == 422
    assert (
        response.json()["detail"][0]["msg"]
        == "part 1 has 5 bytes, expected 1048576: upload it again"
    )
    over = client.post(
        f"{file['upload_url']}/parts", json={"part_numbers": [2]}, headers=auth(token)
    )
    assert over.status_code == 422
    assert over.json()["detail"][0]["msg"] == "this file has 1 parts of 5242880 bytes"


def test_replace_resets_a_file(s3_api_service: Service, videos: dict) -> None:
    client = s3_api_service.client
    token, job = new_job(s3_api_service, videos)
    url = job["files"][1]["upload_url"]
    put_parts(client, token, url, videos[2][0].read_bytes(), [1])
    replacement = {
        "camera": 2,
        "chapter": 0,
        "filename": "GS010002-fixed.mp4",
        "size": 10,
        "sha256": "c" * 64,
    }
    response = client.post(f"{url}/replace", json=replacement, headers=auth(token))
    assert response.status_code == 200, response.text
    status = response.json()
    assert (status["filename"], status["size"], status["upload_state"]) == (
        "GS010002-fixed.mp4",
        10,
        "pending",
    )
    assert status["uploaded_parts"] == [] and status["received_bytes"] == 0
    mismatch = client.post(
        f"{url}/replace", json={**replacement, "chapter": 1}, headers=auth(token)
    )
    assert mismatch.status_code == 422
