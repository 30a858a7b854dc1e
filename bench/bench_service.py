"""Load figures of the service on this machine (a script, not a test: prints numbers).

    .venv/bin/python -m bench.bench_service [--upload-mib 512] [--seconds 10]

Starts its own database, ``firefly3d serve`` and ``firefly3d worker`` subprocesses on the
machine's PostgreSQL and Redis, with local storage, and measures:

1. a streamed upload of a large file through the API: throughput and the API processes'
   peak memory growth, as a fraction of the file size (constant memory: ≪ 1); and the
   same file sent part by part with per-part checksums, as the upload page does;
2. status polling under concurrent clients: requests/s and latency (p50, p99) of
   ``GET /jobs/{id}`` as a ratio to ``GET /healthz`` measured in the same run, with
   ``If-None-Match`` (304s), and while a 1 GiB upload streams through the API;
3. one simulated 20 s stereo job: wall time from submit to success, and the stages'
   summed compute time over it (the parallelism the chunked tracking achieves).
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
from alembic import command

from services.core.db import make_engine, make_session_factory
from tests.services.conftest import (
    alembic_config,
    create_database,
    drop_database,
    free_port,
    make_settings,
    settings_env,
)
from tests.services.helpers import TEST_PARAMS, declare, make_team, sha256

FIREFLY3D = str(Path(sys.executable).with_name("firefly3d"))
MiB = 1 << 20


def rss_bytes(pid: int) -> int:
    """Resident memory of a process and its children (``serve`` runs several processes)."""
    total = 0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            total += int(line.split()[1]) * 1024
    children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    return total + sum(rss_bytes(int(child)) for child in children)


class PeakMemory:
    """Samples a process's resident memory every 20 ms while in use."""

    def __init__(self, pid: int) -> None:
        self.pid, self.peak, self.running = pid, rss_bytes(pid), True
        self.thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while self.running:
            self.peak = max(self.peak, rss_bytes(self.pid))
            time.sleep(0.02)

    def __enter__(self) -> PeakMemory:
        self.thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self.running = False
        self.thread.join()


def chunks(path: Path, size: int = 4 * MiB) -> Iterator[bytes]:
    with path.open("rb") as handle:
        while block := handle.read(size):
            yield block


def random_file(path: Path, mib: int) -> Path:
    if not path.exists():
        with path.open("wb") as out:
            for _ in range(mib // 16):
                out.write(os.urandom(16 * MiB))
    return path


def upload_file(api: str, headers: dict[str, str], tmp: Path, mib: int) -> float:
    """Declare a job and stream a `mib` MiB camera-1 file in one PUT; returns seconds."""
    big = random_file(tmp / f"GS01{mib:04d}.mp4", mib)
    small = tmp / "GS010002.mp4"
    small.write_bytes(os.urandom(MiB))
    night = httpx.post(
        f"{api}/api/v1/nights",
        json={"site": "bench", "date": "2026-06-01", "separation_m": 1.5},
        headers=headers,
    ).json()
    job = httpx.post(
        f"{api}/api/v1/jobs",
        json={"night_id": night["id"], "files": declare({1: [big], 2: [small]})},
        headers=headers,
    ).json()
    url = api + job["files"][0]["upload_url"]
    started = time.perf_counter()
    response = httpx.put(url, content=chunks(big), headers=headers, timeout=600)
    seconds = time.perf_counter() - started
    assert response.status_code == 200 and response.json()["upload_state"] == "uploaded", (
        response.text
    )
    return seconds


def upload_parts(api: str, headers: dict[str, str], tmp: Path, mib: int) -> float:
    """As the page does: no declared SHA-256, one PUT per part with its checksum header
    (the API hashes each part as it writes it and checks it); returns seconds."""
    big = random_file(tmp / f"GS01{mib:04d}.mp4", mib)
    small = tmp / "GS010002.mp4"
    declared = [{**f, "sha256": None} for f in declare({1: [big], 2: [small]})]
    night = {"site": "bench", "date": "2026-06-01", "separation_m": 1.5}
    job = httpx.post(
        f"{api}/api/v1/jobs", json={"night": night, "files": declared}, headers=headers
    ).json()
    file = job["files"][0]
    url, size, part = api + file["upload_url"], file["size"], file["part_size"]
    started = time.perf_counter()
    with httpx.Client(headers=headers, timeout=600) as http, big.open("rb") as handle:
        for offset in range(0, size, part):
            data = handle.read(part)
            checksum = base64.b64encode(hashlib.sha256(data).digest()).decode()
            response = http.put(
                url,
                content=data,
                headers={
                    "Content-Range": f"bytes {offset}-{offset + len(data) - 1}/{size}",
                    "x-amz-checksum-sha256": checksum,
                },
            )
            assert response.status_code == 200, response.text
    assert response.json()["upload_state"] == "uploaded" and response.json()["checksum"]
    return time.perf_counter() - started


def bench_upload(api: str, headers: dict[str, str], server_pid: int, tmp: Path, mib: int) -> None:
    before = rss_bytes(server_pid)
    with PeakMemory(server_pid) as memory:
        seconds = upload_file(api, headers, tmp, mib)
    growth = memory.peak - before
    print(
        f"streamed upload   {mib} MiB in {seconds:.1f} s = {mib / seconds:.0f} MiB/s "
        f"(SHA-256 check included); API peak memory growth {growth / MiB:.1f} MiB "
        f"= {growth / (mib * MiB):.3f} × the file size"
    )
    seconds = upload_parts(api, headers, tmp, mib)
    print(
        f"part uploads      {mib} MiB in {seconds:.1f} s = {mib / seconds:.0f} MiB/s (one PUT "
        "per part with x-amz-checksum-sha256, hashed and checked by the API, as the page "
        "sends; the client's hashing included)"
    )


CLIENTS = 8


def latencies(
    call: Callable[[], httpx.Response], seconds: float, busy: Callable[[], bool] | None = None
) -> tuple[list[float], float]:
    """Latencies of `call` from `CLIENTS` threads for `seconds` (or while `busy()`);
    returns them with the elapsed time."""
    started = time.perf_counter()
    deadline = started + seconds

    def worker() -> list[float]:
        times = []
        while time.perf_counter() < deadline if busy is None else busy():
            t0 = time.perf_counter()
            assert call().status_code in (200, 304)
            times.append(time.perf_counter() - t0)
        return times

    with ThreadPoolExecutor(CLIENTS) as pool:
        times = [t for result in pool.map(lambda _: worker(), range(CLIENTS)) for t in result]
    return times, time.perf_counter() - started


def figures(measured: tuple[list[float], float]) -> str:
    times, seconds = measured
    q = statistics.quantiles(times, n=100)
    return (
        f"{len(times) / seconds:.0f} req/s (p50 {1000 * statistics.median(times):.1f} ms, "
        f"p99 {1000 * q[98]:.1f} ms)"
    )


def rate(measured: tuple[list[float], float]) -> float:
    return len(measured[0]) / measured[1]


def bench_polling(
    api: str, headers: dict[str, str], job_id: str, seconds: float, tmp: Path, upload_mib: int
) -> None:
    """Status polling beside /healthz; with ETags (304s); and while a big upload runs."""
    with httpx.Client(
        base_url=api, headers=headers, limits=httpx.Limits(max_connections=CLIENTS)
    ) as http:
        path = f"/api/v1/jobs/{job_id}"
        base = latencies(lambda: http.get("/healthz"), seconds)
        plain = latencies(lambda: http.get(path), seconds)
        etag = http.get(path).headers["etag"]
        cached = latencies(lambda: http.get(path, headers={"If-None-Match": etag}), seconds)
        upload = threading.Thread(
            target=upload_file, args=(api, headers, tmp, upload_mib), daemon=True
        )
        upload.start()
        during = latencies(lambda: http.get(path), seconds, busy=upload.is_alive)
        upload.join()
    print(f"/healthz          {CLIENTS} clients: {figures(base)}")
    print(
        f"status polling    {CLIENTS} clients: GET /jobs/{{id}} {figures(plain)} "
        f"= {rate(plain) / rate(base):.2f} × /healthz"
    )
    print(
        f"                  with If-None-Match (304): {figures(cached)} "
        f"= {rate(cached) / rate(base):.2f} × /healthz"
    )
    print(f"                  while a {upload_mib} MiB upload runs: {figures(during)}")


def bench_job(api: str, headers: dict[str, str], tmp: Path) -> str:
    from pipeline.simulate import SimulationConfig, simulate

    recording = simulate(
        SimulationConfig(width=640, seconds=20, chapters=(1, 2), seed=5), tmp / "rec"
    )
    cameras = {1: list(recording.cam1), 2: list(recording.cam2)}
    night = httpx.post(
        f"{api}/api/v1/nights",
        json={"site": "bench", "date": "2026-06-01", "separation_m": 1.5},
        headers=headers,
    ).json()
    body = {"night_id": night["id"], "files": declare(cameras), "params": TEST_PARAMS}
    job = httpx.post(f"{api}/api/v1/jobs", json=body, headers=headers).json()
    for file in job["files"]:
        path = cameras[file["camera"]][file["chapter"]]
        assert sha256(path) == file["sha256"]
        httpx.put(api + file["upload_url"], content=path.read_bytes(), headers=headers, timeout=120)
    started = time.perf_counter()
    httpx.post(f"{api}/api/v1/jobs/{job['id']}/submit", headers=headers)
    while (state := httpx.get(f"{api}/api/v1/jobs/{job['id']}", headers=headers).json())[
        "status"
    ] not in ("succeeded", "failed"):
        time.sleep(0.2)
    wall = time.perf_counter() - started
    assert state["status"] == "succeeded", state["error"]
    compute = sum(s["metrics"].get("seconds", 0.0) for s in state["stages"])
    chunks_n = sum(s["name"] == "track" for s in state["stages"])
    print(
        f"one job           20 s stereo 640×320, {chunks_n} tracking chunks, 1 worker × 2 "
        f"processes: {wall:.1f} s submit → succeeded; stage compute {compute:.1f} s "
        f"= {compute / wall:.2f} × wall time"
    )
    return str(job["id"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--upload-mib", type=int, default=512)
    parser.add_argument("--seconds", type=float, default=10.0, help="length of the polling run")
    parser.add_argument(
        "--busy-upload-mib", type=int, default=1024, help="upload beside the last polling run"
    )
    args = parser.parse_args()

    url = create_database("firefly3d_bench")
    command.upgrade(alembic_config(url), "head")
    engine = make_engine(url)
    processes: list[subprocess.Popen[bytes]] = []
    try:
        with tempfile.TemporaryDirectory(prefix="firefly3d-bench-") as tmp_dir:
            tmp = Path(tmp_dir)
            settings = make_settings(url, f"bench-{uuid.uuid4().hex[:8]}:", tmp, backend="local")
            env = {k: v for k, v in os.environ.items() if not k.startswith("FIREFLY3D_")}
            env |= settings_env(settings)
            port = free_port()
            processes.append(
                subprocess.Popen(
                    [FIREFLY3D, "serve", "--port", str(port)],
                    env=env,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
            processes.append(
                subprocess.Popen(
                    [FIREFLY3D, "worker", "--concurrency", "2"],
                    env=env,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
            api = f"http://127.0.0.1:{port}"
            for _ in range(300):
                try:
                    httpx.get(f"{api}/healthz")
                    break
                except httpx.TransportError:
                    time.sleep(0.1)
            headers = {"Authorization": f"Bearer {make_team(make_session_factory(engine))}"}
            bench_upload(api, headers, processes[0].pid, tmp, args.upload_mib)
            job_id = bench_job(api, headers, tmp)
            bench_polling(api, headers, job_id, args.seconds, tmp, args.busy_upload_mib)
    finally:
        for process in processes:
            process.terminate()
            process.wait(timeout=60)
        engine.dispose()
        drop_database(url)


if __name__ == "__main__":
    main()
