"""The upload form and the job page in headless Chromium (Debian's, driven by Playwright)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Browser, Page, sync_playwright

from pipeline.artifacts import SUMMARY_JSON, TRAJECTORIES_CSV
from tests.services.conftest import LiveServer, Service
from tests.services.helpers import NIGHT, TEST_PARAMS, auth, create_job, make_team

pytestmark = pytest.mark.slow
CHROMIUM_FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
]
#: Records every state and progress value the upload table shows, before the page leaves.
WATCH_UPLOADS = """
new MutationObserver(() => {
  for (const row of document.querySelectorAll('#files tbody tr')) {
    window.recordUpload(row.cells[2].textContent, row.cells[3].textContent,
                        row.querySelector('progress').value);
  }
}).observe(document.querySelector('#files'), {subtree: true, childList: true, characterData: true,
                                               attributes: true});
"""


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    executable = shutil.which("chromium")
    assert executable, "Debian's chromium is needed: apt-get install -y chromium"
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=executable, headless=True, args=CHROMIUM_FLAGS
        )
        yield browser
        browser.close()


def upload_through_the_form(
    page: Page, server: LiveServer, token: str, recording: dict
) -> list[tuple]:
    seen: list[tuple] = []
    page.goto(f"{server.url}/")
    page.expose_function("recordUpload", lambda *state: seen.append(state))
    page.evaluate(WATCH_UPLOADS)
    page.fill("#token", token)
    page.fill("#site", NIGHT["site"])
    page.fill("#date", NIGHT["date"])
    page.fill("#separation", str(NIGHT["separation_m"]))
    page.fill("#height", str(NIGHT["height_m"]))
    page.set_input_files("#cam1-files", [str(p) for p in recording[1]])
    page.set_input_files("#cam2-files", [str(p) for p in reversed(recording[2])])  # sorted by name
    assert page.locator("#cam2-list li").all_inner_texts()[0].startswith(recording[2][0].name)
    page.click("text=Advanced")
    page.fill("#params", json.dumps(TEST_PARAMS))
    page.click("#start")
    page.wait_for_url("**/jobs/*", timeout=120_000)
    return seen


def check_job_page(page: Page, server: LiveServer, reference: Path) -> None:
    page.wait_for_selector("#job-status.status-succeeded", timeout=240_000)
    rows = page.locator("#stages tbody tr")
    assert rows.count() == 16  # 8 stages + 4 tracking chunks per camera
    assert set(page.locator("#stages tbody tr td:nth-child(2)").all_inner_texts()) == {"succeeded"}
    shown = dict(
        zip(
            page.locator("#summary-list dt").all_inner_texts(),
            page.locator("#summary-list dd").all_inner_texts(),
            strict=True,
        )
    )
    summary = json.loads((reference / SUMMARY_JSON).read_text())
    assert shown["counts.trajectories"] == str(summary["counts"]["trajectories"])
    flooded = summary["tracking"]["cam1"]["flooded_frames"]
    assert shown["tracking.cam1.flooded_frames"] == str(flooded)  # what tracking dropped
    link = page.locator("#results a", has_text=TRAJECTORIES_CSV)
    with page.expect_download() as download:
        link.click()
    assert Path(download.value.path()).read_bytes() == (reference / TRAJECTORIES_CSV).read_bytes()
    plots = page.locator("#plots img")
    assert plots.count() >= 3
    for i in range(plots.count()):
        assert plots.nth(i).evaluate("img => img.complete && img.naturalWidth > 0")


@pytest.mark.parametrize("backend", ["s3", "local"])
def test_upload_form_to_results(
    backend: str,
    browser: Browser,
    request: pytest.FixtureRequest,
    recording: dict,
    reference: Path,
    tmp_path: Path,
) -> None:
    service: Service = request.getfixturevalue(f"{backend}_service")
    request.getfixturevalue(f"{backend}_worker")
    token = make_team(service.sessions)
    page = browser.new_page(accept_downloads=True)
    with LiveServer(service) as server:
        seen = upload_through_the_form(page, server, token, recording)
        states = {state for _, state, _ in seen}
        assert {"checksum", "uploading", "uploaded"} <= states
        partial = [
            value
            for name, state, value in seen
            if name == recording[1][0].name and state == "uploading"
        ]
        assert any(0 < v < 1 for v in partial)  # the bar moved during the upload
        check_job_page(page, server, reference)
        page.screenshot(path=str(tmp_path / f"job-{backend}.png"), full_page=True)
    page.close()


def test_upload_resumes_after_a_reload(
    s3_api_service: Service, browser: Browser, recording: dict
) -> None:
    """A page reloaded mid-upload continues the same job and skips the stored parts."""
    client = s3_api_service.client
    token = make_team(s3_api_service.sessions)
    job = create_job(client, token, recording)  # what the first visit created…
    first = job["files"][0]
    signed = client.post(
        f"{first['upload_url']}/parts", json={"part_numbers": [1]}, headers=auth(token)
    )
    data = recording[1][0].read_bytes()
    assert (
        httpx.put(signed.json()["parts"][0]["url"], content=data[: first["part_size"]]).status_code
        == 200
    )

    requests: list[str] = []
    page = browser.new_page()
    page.on("request", lambda r: requests.append(f"{r.method} {r.url}"))
    with LiveServer(s3_api_service) as server:
        page.goto(f"{server.url}/")
        page.set_input_files("#cam1-files", [str(p) for p in recording[1]])
        page.set_input_files("#cam2-files", [str(p) for p in recording[2]])
        modified = page.evaluate(
            "[1, 2].flatMap(c => [...document.querySelector(`#cam${c}-files`).files]"
            ".map(f => `${f.name}|${f.size}|${f.lastModified}`))"
        )
        saved = {  # …and remembered before the connection dropped
            "jobId": job["id"],
            "night": NIGHT,
            "files": [
                {"fingerprint": m, "sha256": f["sha256"]}
                for m, f in zip(modified, job["files"], strict=True)
            ],
        }
        page.evaluate(f"localStorage.setItem('firefly3d.upload', {json.dumps(json.dumps(saved))})")
        page.evaluate(f"localStorage.setItem('firefly3d.token', '{token}')")
        page.reload()
        assert "was interrupted" in page.inner_text("#status")
        assert page.input_value("#site") == NIGHT["site"]  # the night is filled in again
        page.set_input_files("#cam1-files", [str(p) for p in recording[1]])
        page.set_input_files("#cam2-files", [str(p) for p in recording[2]])
        page.click("#start")
        page.wait_for_url(f"**/jobs/{job['id']}", timeout=120_000)
    page.close()

    assert not [
        r for r in requests if r.startswith("POST") and r.endswith(("/api/v1/jobs", "/nights"))
    ]
    first_file_parts = [r for r in requests if r.startswith("PUT") and "/input/cam1/00.mp4?" in r]
    assert len(first_file_parts) == first["part_count"] - 1
    assert not any("partNumber=1&" in r or r.endswith("partNumber=1") for r in first_file_parts)
    status = client.get(f"/api/v1/jobs/{job['id']}", headers=auth(token)).json()
    assert status["status"] == "queued"
    assert {f["upload_state"] for f in status["files"]} == {"uploaded"}
