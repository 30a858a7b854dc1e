"""The upload form and the job page in headless Chromium (Debian's, driven by Playwright)."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import Browser, Page, Route, sync_playwright

from pipeline.artifacts import SUMMARY_JSON, TRAJECTORIES_CSV
from pipeline.results import read_trajectories
from services.domain.access import authenticate
from tests.services.conftest import LINK_LIFETIME_S, LiveServer, Service
from tests.services.helpers import NIGHT, TEST_PARAMS, auth, make_team

pytestmark = pytest.mark.slow
MiB = 1 << 20
CHROMIUM_FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    # WebGL (the job page's 3D view) on the CPU: Chromium's SwiftShader, allowed explicitly
    # since Chromium no longer falls back to it by itself.
    "--enable-unsafe-swiftshader",
]
#: Pixels of the 3D view that differ from its background (#0b1020), counted in the page.
LIT_PIXELS = """() => {
  const gl = document.querySelector('#viewer-canvas');
  const copy = document.createElement('canvas');
  copy.width = gl.width; copy.height = gl.height;
  const ctx = copy.getContext('2d');
  ctx.drawImage(gl, 0, 0);
  const data = ctx.getImageData(0, 0, copy.width, copy.height).data;
  let lit = 0;
  for (let i = 0; i < data.length; i += 4) {
    const off = Math.abs(data[i] - 11) + Math.abs(data[i + 1] - 16) + Math.abs(data[i + 2] - 32);
    if (off > 60) lit++;
  }
  return lit;
}"""
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
    page.fill("#latitude", str(NIGHT["latitude"]))
    page.fill("#longitude", str(NIGHT["longitude"]))
    page.fill("#time-zone", NIGHT["time_zone"])
    page.fill("#start-time", NIGHT["start_time"])
    page.fill("#camera-model", NIGHT["camera_model"])
    page.set_input_files("#cam1-files", [str(p) for p in recording[1]])
    page.set_input_files("#cam2-files", [str(p) for p in reversed(recording[2])])  # sorted by name
    assert page.locator("#cam2-list li").all_inner_texts()[0].startswith(recording[2][0].name)
    page.click("text=Advanced")
    page.fill("#params", json.dumps(TEST_PARAMS))
    page.click("#start")
    try:
        page.wait_for_url("**/jobs/*", timeout=120_000)
    except Exception:
        raise AssertionError(f"the upload did not finish: {page.inner_text('#status')}") from None
    return seen


def team_name(service: Service, token: str) -> str:
    with service.sessions() as session:
        principal = authenticate(session, service.settings, token)
        assert principal.team is not None
        return principal.team.name


def check_job_page(page: Page, team: str, reference: Path) -> None:
    page.wait_for_selector("#job-status.status-succeeded", timeout=240_000)
    rows = page.locator("#stages tbody tr")
    assert rows.count() == 20  # 12 stages + 4 tracking chunks per camera
    assert set(page.locator("#stages tbody tr td:nth-child(2)").all_inner_texts()) == {"succeeded"}
    assert page.inner_text("#job-title") == f"{NIGHT['site']}, {NIGHT['date']} — {team}"

    def shown(key: str) -> tuple[str, str]:
        return (
            page.inner_text(f'#summary-list dt[data-key="{key}"]'),
            page.inner_text(f'#summary-list dd[data-key="{key}"]'),
        )

    summary = json.loads((reference / SUMMARY_JSON).read_text())
    trajectories = f"{summary['counts']['trajectories']:,}"
    assert shown("counts.trajectories") == ("Trajectories", trajectories)
    flooded = summary["tracking"]["cam1"]["flooded_frames"]
    assert shown("tracking.cam1.flooded_frames") == (
        "Frames too bright to track, camera 1",
        str(flooded),
    )
    label, value = shown("delay_confidence")
    assert label == "Delay confidence" and value.endswith(" %")
    label, value = shown("delay_set_aside.cam1")
    assert label.startswith("Frames the delay search set aside")
    assert value == str(summary["delay_set_aside"]["cam1"]) and int(value) > 0
    label, value = shown("pose_refit.rotation_change_deg")
    assert label == "Pose refit: rotation change from the first pose" and value.endswith(" °")
    plots = page.locator("#plots img")
    assert plots.count() >= 3
    for i in range(plots.count()):
        assert plots.nth(i).evaluate("img => img.complete && img.naturalWidth > 0")

    page.wait_for_timeout(1000 * (LINK_LIFETIME_S + 1))  # links listed at load have expired
    link = page.locator("#results a", has_text=TRAJECTORIES_CSV)
    with page.expect_download() as download:
        link.click()  # signed on click: still works
    assert Path(download.value.path()).read_bytes() == (reference / TRAJECTORIES_CSV).read_bytes()
    with page.expect_download() as archive:
        page.click("#download-all")
    with zipfile.ZipFile(archive.value.path()) as results:
        assert results.read(TRAJECTORIES_CSV) == (reference / TRAJECTORIES_CSV).read_bytes()
        assert SUMMARY_JSON in results.namelist()
        package = json.loads(results.read("datapackage.json"))
    assert package["night"]["site"] == NIGHT["site"]
    assert {r["path"] for r in package["resources"]} >= {TRAJECTORIES_CSV, "flash_patterns.csv"}
    check_viewer(page, reference)


def set_range(page: Page, selector: str, value: float) -> float:
    """Move a slider as a person would (it snaps to its step); returns where it stopped."""
    return float(
        page.eval_on_selector(
            selector,
            "(input, value) => { input.value = value; input.dispatchEvent(new Event('input'));"
            " return input.value; }",
            str(value),
        )
    )


def check_viewer(page: Page, reference: Path) -> None:
    """The 3D view draws the whole night, then only the flashes of the chosen window."""
    page.wait_for_selector("#viewer:not([hidden])")
    assert page.is_hidden("#viewer-error"), page.inner_text("#viewer-error")
    page.wait_for_function("Number(document.querySelector('#viewer-canvas').dataset.renders) > 0")
    times = read_trajectories(reference / TRAJECTORIES_CSV)["time_s"]
    canvas = page.locator("#viewer-canvas")
    assert int(canvas.get_attribute("data-visible") or -1) == len(times)
    whole = page.evaluate(LIT_PIXELS)
    assert whole > 500  # points, trajectory lines, cameras and ground drawn
    page.uncheck("#viewer-trails")
    set_range(page, "#viewer-width", 2)
    shown = []
    for end in (np.quantile(times, 0.3), np.quantile(times, 0.8)):
        end = set_range(page, "#viewer-time", end)
        expected = int(np.count_nonzero((times >= end - 2 - 1e-6) & (times <= end + 1e-6)))
        assert int(canvas.get_attribute("data-visible") or -1) == expected
        shown.append((expected, page.evaluate(LIT_PIXELS)))
    assert page.is_checked("#viewer-whole") is False
    (n1, lit1), (n2, lit2) = shown
    assert 0 < n1 < len(times) and 0 < n2 < len(times)
    assert lit1 < whole and lit2 < whole and lit1 != lit2  # the slider changed the picture


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
        assert {"uploading", "uploaded"} <= states
        partial = [
            value
            for name, state, value in seen
            if name == recording[1][0].name and state == "uploading"
        ]
        assert any(0 < v < 1 for v in partial)  # the bar moved during the upload
        check_job_page(page, team_name(service, token), reference)
        page.screenshot(path=str(tmp_path / f"job-{backend}.png"), full_page=True)
    page.close()


def fill_night(page: Page, token: str) -> None:
    page.fill("#token", token)
    page.fill("#site", NIGHT["site"])
    page.fill("#date", NIGHT["date"])
    page.fill("#separation", str(NIGHT["separation_m"]))


def test_wrong_token_is_refused_before_any_hashing(
    api_service: Service, browser: Browser, big_files: dict
) -> None:
    page = browser.new_page()
    started_workers: list[str] = []
    page.on("worker", lambda worker: started_workers.append(worker.url))
    with LiveServer(api_service) as server:
        page.goto(f"{server.url}/")
        fill_night(page, "ff3d_not-a-token")
        page.set_input_files("#cam1-files", [str(big_files[1])])
        page.set_input_files("#cam2-files", [str(big_files[2])])
        page.click("#start")
        page.wait_for_selector("#status:has-text('error: invalid, revoked or expired token')")
    page.close()
    assert started_workers == []  # the hashing worker never started


@pytest.fixture(scope="module")
def big_files(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    """Random stand-ins for videos: camera 1 in 3 parts of 5 MiB, camera 2 in one."""
    out = tmp_path_factory.mktemp("big")
    files = {1: out / "GS010001.mp4", 2: out / "GS010002.mp4"}
    files[1].write_bytes(os.urandom(12 * MiB + 321))
    files[2].write_bytes(os.urandom(MiB))
    return files


def test_upload_resumes_after_a_reload(
    s3_api_service: Service, browser: Browser, big_files: dict
) -> None:
    """A page reloaded mid-upload continues the same job and skips the stored parts."""
    client = s3_api_service.client
    token = make_team(s3_api_service.sessions)
    puts: list[str] = []
    page = browser.new_page()
    page.on("request", lambda r: puts.append(r.url) if r.method == "PUT" else None)

    def only_part_one(route: Route) -> None:  # the connection drops for the other parts
        if "partNumber=1&" in route.request.url or route.request.url.endswith("partNumber=1"):
            route.continue_()
        else:
            route.abort("connectionreset")

    with LiveServer(s3_api_service) as server:
        page.goto(f"{server.url}/")
        page.route("**/input/cam1/00.mp4?*", only_part_one)
        fill_night(page, token)
        page.set_input_files("#cam1-files", [str(big_files[1])])
        page.set_input_files("#cam2-files", [str(big_files[2])])
        page.click("#start")
        page.wait_for_selector("#status:has-text('retrying')")
        job_id = json.loads(page.evaluate("localStorage.getItem('firefly3d.upload')"))["jobId"]
        url = f"/api/v1/jobs/{job_id}/files/1/0"
        deadline = time.monotonic() + 30
        while client.get(url, headers=auth(token)).json()["uploaded_parts"] != [1]:
            assert time.monotonic() < deadline, "part 1 was not stored"
            time.sleep(0.1)
        page.unroute("**/input/cam1/00.mp4?*")
        before = len(puts)
        page.reload()
        assert "was interrupted" in page.inner_text("#status")
        assert page.input_value("#site") == NIGHT["site"]  # the night is filled in again
        page.set_input_files("#cam1-files", [str(big_files[1])])
        page.set_input_files("#cam2-files", [str(big_files[2])])
        page.click("#start")
        page.wait_for_url(f"**/jobs/{job_id}", timeout=120_000)
    page.close()

    resumed = [u for u in puts[before:] if "/input/cam1/00.mp4?" in u]
    assert sorted(re.search(r"partNumber=(\d+)", u)[1] for u in resumed) == ["2", "3"]  # type: ignore[index]
    status = client.get(f"/api/v1/jobs/{job_id}", headers=auth(token)).json()
    assert status["status"] == "queued"
    assert {f["upload_state"] for f in status["files"]} == {"uploaded"}
    digests = [
        hashlib.sha256(big_files[1].read_bytes()[i : i + 5 * MiB]).digest()
        for i in range(0, big_files[1].stat().st_size, 5 * MiB)
    ]
    assert status["files"][0]["checksum"] == hashlib.sha256(b"".join(digests)).hexdigest()
