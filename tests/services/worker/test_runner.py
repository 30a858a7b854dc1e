"""Claiming a stage delivery: tokens, duplicates, bounded deliveries; input verification."""

from __future__ import annotations

import math
import uuid
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pipeline.jsonio import json_safe
from services.core.checksums import file_checksums
from services.core.db import SessionFactory
from services.core.models import Job
from services.core.settings import Settings
from services.core.storage.local import LocalStorage
from services.domain.workflow import StageMessage
from services.worker.inputs import InputCache, InputError, InputRef
from services.worker.runner import Runtime, backoff_s, claim, time_limit_message
from tests.services.helpers import queued_stage, stage_row


@pytest.fixture
def runtime(sessions: SessionFactory, tmp_path: Path) -> tuple[Runtime, list[StageMessage]]:
    sent: list[StageMessage] = []
    settings = Settings(max_attempts=3, work_dir=tmp_path / "work", database_url="unused")
    storage = LocalStorage(tmp_path / "store")
    cache = InputCache(tmp_path / "cache", 1 << 30)
    return Runtime(settings, sessions, storage, sent.extend, cache), sent


def test_claim_marks_running_and_counts(
    runtime: tuple[Runtime, list], sessions: SessionFactory
) -> None:
    rt, _ = runtime
    job_id, key, token = queued_stage(sessions)
    ctx = claim(rt, job_id, key, token)
    assert ctx is not None and (ctx.attempt, ctx.deliveries, ctx.separation_m) == (1, 1, 1.5)
    row = stage_row(sessions, job_id)
    assert (row.status, row.attempt, row.warnings) == ("running", 1, [])
    again = claim(rt, job_id, key, token)  # redelivered after its worker died
    assert again is not None and again.attempt == 2
    assert stage_row(sessions, job_id).warnings == ["attempt 1: the worker was lost"]


def test_stale_token_is_ignored(runtime: tuple[Runtime, list], sessions: SessionFactory) -> None:
    rt, _ = runtime
    job_id, key, _ = queued_stage(sessions)
    assert claim(rt, job_id, key, "0" * 32) is None
    assert stage_row(sessions, job_id).status == "queued"


def test_duplicate_of_a_finished_stage_only_advances(
    runtime: tuple[Runtime, list], sessions: SessionFactory
) -> None:
    rt, sent = runtime
    job_id, key, token = queued_stage(sessions, status="succeeded")
    assert claim(rt, job_id, key, token) is None
    with sessions() as session:
        assert session.get_one(Job, uuid.UUID(job_id)).status == "succeeded"  # its only stage
    assert sent == []


def test_deliveries_are_bounded(runtime: tuple[Runtime, list], sessions: SessionFactory) -> None:
    rt, _ = runtime
    job_id, key, token = queued_stage(sessions, deliveries=3, status="running")
    assert claim(rt, job_id, key, token) is None
    row = stage_row(sessions, job_id)
    assert row.status == "failed" and row.error.startswith("gave up after 3 attempts")
    with sessions() as session:
        job = session.get_one(Job, uuid.UUID(job_id))
        assert job.status == "failed" and job.error == f"sync failed: {row.error}"


def test_backoff_grows_and_is_capped() -> None:
    settings = Settings(retry_backoff_s=2, retry_backoff_max_s=30)
    delays = [[backoff_s(settings, attempt) for _ in range(200)] for attempt in (1, 2, 3, 10)]
    assert all(
        min(d) >= 0.5 * m and max(d) <= m for d, m in zip(delays, (2, 4, 8, 30), strict=True)
    )


def test_json_safe_metrics() -> None:
    metrics = {
        "n": np.int64(3),
        "x": np.float32(0.5),
        "bad": math.nan,
        "v": np.arange(2),
        "k": {1: math.inf},
    }
    assert json_safe(metrics) == {"n": 3, "x": 0.5, "bad": None, "v": [0, 1], "k": {"1": None}}


def test_input_cache_verifies_and_reuses(tmp_path: Path) -> None:
    storage = LocalStorage(tmp_path / "store")
    source = tmp_path / "GS010001.mp4"
    source.write_bytes(b"video" * 1000)
    storage.upload_file(source, "jobs/j/input/cam1/00.mp4", "video/mp4")
    whole, parts = file_checksums(source, 2048)
    ref = InputRef(1, 0, source.name, "jobs/j/input/cam1/00.mp4", 5000, whole, 2048, parts)
    cache = InputCache(tmp_path / "cache", max_bytes=6000)
    first = cache.fetch(storage, ref, tmp_path / "a" / source.name)
    storage.delete(ref.storage_key)  # a second fetch must come from the cache
    second = cache.fetch(storage, ref, tmp_path / "b" / source.name)
    assert first.read_bytes() == second.read_bytes() == source.read_bytes()

    wrong = InputRef(1, 1, "GS020001.mp4", "jobs/j/input/cam1/01.mp4", 5000, "0" * 64, 2048, None)
    storage.upload_file(source, wrong.storage_key, "video/mp4")
    with pytest.raises(
        InputError, match=r"camera 1 chapter 1 \(GS020001.mp4\): SHA-256 of the uploaded"
    ):
        cache.fetch(storage, wrong, tmp_path / "c" / "x.mp4")
    # Without a declared SHA-256 (the upload page declares none) the parts' checksum counts.
    undeclared = replace(wrong, sha256=None, checksum="1" * 64)
    with pytest.raises(InputError, match="checksum of the part checksums is " + parts):
        cache.fetch(storage, undeclared, tmp_path / "c" / "y.mp4")
    short = replace(wrong, size=4000, sha256=ref.sha256)
    with pytest.raises(InputError, match="stored file has 5000 bytes, declared 4000"):
        cache.fetch(storage, short, tmp_path / "d" / "x.mp4")
    entries = [p.name for p in (tmp_path / "cache").iterdir()]
    assert entries == [cache.path_for(ref).name]  # no partial downloads left

    other = tmp_path / "other.mp4"
    other.write_bytes(b"other" * 1000)
    storage.upload_file(other, "jobs/j/input/cam2/00.mp4", "video/mp4")
    newer = InputRef(2, 0, "o.mp4", "jobs/j/input/cam2/00.mp4", 5000, None, 2048, None)
    cache.fetch(storage, newer, tmp_path / "e" / "o.mp4")  # over 6000 bytes: oldest evicted
    assert [p.name for p in (tmp_path / "cache").iterdir()] == [cache.path_for(newer).name]
    assert first.read_bytes() == source.read_bytes()  # a hard link outlives eviction


def test_time_limit_message_names_what_to_change(
    runtime: tuple[Runtime, list], sessions: SessionFactory
) -> None:
    rt, _ = runtime
    chunk = claim(rt, *queued_stage(sessions, name="track"))
    whole = claim(rt, *queued_stage(sessions, name="sync"))
    assert chunk is not None and whole is not None
    assert time_limit_message(rt.settings, chunk).endswith(
        "(FIREFLY3D_TASK_SOFT_TIME_LIMIT_S): re-run with a smaller chunk_s (now 60 s) so that "
        "each chunk fits"
    )
    assert "chunk_s" not in time_limit_message(rt.settings, whole)
