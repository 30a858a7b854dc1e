"""Jobs: creation with upload instructions, and their status as the API shows it."""

from __future__ import annotations

import uuid
from typing import Any

from pydantic import ValidationError
from sqlalchemy.orm import Session

from pipeline.run import ProcessParams
from services.api.deps import Principal, night_for, unprocessable
from services.api.schemas import FileOut, JobCreate, JobOut, StageOut
from services.core.models import InputFile, Job, JobStatus, Stage, StageStatus, Team, UploadState
from services.core.settings import Settings
from services.core.storage import Storage, part_size_for
from services.core.workflow import STAGES, job_key

API_PREFIX = "/api/v1"
#: Stages whose metrics make a job's summary.
SUMMARY_STAGES = ("sync", "pose", "triangulate", "link")


def input_key(job_id: uuid.UUID, camera: int, chapter: int) -> str:
    """Storage key of an input video (the uploaded name is kept only as metadata)."""
    return job_key(job_id, f"input/cam{camera}/{chapter:02d}.mp4")


def merged_params(base: dict[str, Any], overrides: dict[str, Any] | None) -> dict[str, Any]:
    """`base` parameters with `overrides` deep-merged in, validated (422 if invalid)."""
    try:
        params = ProcessParams.model_validate(base).merged(overrides or {})
    except ValidationError as exc:
        messages = "; ".join(
            f"{'.'.join(map(str, e['loc'])) or 'params'}: {e['msg']}" for e in exc.errors()
        )
        raise unprocessable(["body", "params"], f"invalid parameters: {messages}") from None
    return params.model_dump(mode="json")


def _check_limits(body: JobCreate, settings: Settings) -> None:
    for i, declared in enumerate(body.files):
        if declared.size > settings.max_file_bytes:
            raise unprocessable(
                ["body", "files", i, "size"],
                f"{declared.filename}: declared size {declared.size} bytes exceeds the limit "
                f"of {settings.max_file_bytes} bytes per file",
            )
    for camera in (1, 2):
        count = sum(f.camera == camera for f in body.files)
        if count > settings.max_chapters:
            raise unprocessable(
                ["body", "files"],
                f"camera {camera} has {count} chapters; the limit is {settings.max_chapters}",
            )


def create_job(session: Session, settings: Settings, team: Team, body: JobCreate) -> Job:
    """A job in state ``created`` with its files declared (nothing uploaded yet)."""
    night = night_for(session, Principal(team), body.night_id)
    _check_limits(body, settings)
    params = merged_params(ProcessParams.model_validate({}).model_dump(mode="json"), body.params)
    job = Job(id=uuid.uuid4(), night=night, params=params, status=JobStatus.CREATED)
    job.files = [
        InputFile(
            camera=f.camera,
            chapter=f.chapter,
            filename=f.filename,
            size=f.size,
            sha256=f.sha256,
            storage_key=input_key(job.id, f.camera, f.chapter),
            part_size=part_size_for(f.size, settings.min_part_bytes),
            upload_state=UploadState.PENDING,
        )
        for f in sorted(body.files, key=lambda f: (f.camera, f.chapter))
    ]
    session.add(job)
    session.commit()
    return job


def file_out(job: Job, file: InputFile, storage: Storage) -> FileOut:
    url = f"{API_PREFIX}/jobs/{job.id}/files/{file.camera}/{file.chapter}"
    return FileOut(
        camera=file.camera,
        chapter=file.chapter,
        filename=file.filename,
        size=file.size,
        sha256=file.sha256,
        upload_state=file.upload_state,
        method=storage.upload_mode,
        part_size=file.part_size,
        part_count=-(-file.size // file.part_size),
        upload_url=url,
    )


def job_progress(stages: list[Stage]) -> float:
    """Fraction of the pipeline done: each stage counts equally, chunks averaged."""

    def done(stage: Stage) -> float:
        return 1.0 if stage.status == StageStatus.SUCCEEDED else stage.progress

    fractions = []
    for name in STAGES:
        rows = [s for s in stages if s.name == name]
        fractions.append(sum(map(done, rows)) / len(rows) if rows else 0.0)
    return sum(fractions) / len(STAGES)


def job_summary(stages: list[Stage]) -> dict[str, Any]:
    """Headline metrics (delay, calibration pairs, points, trajectories) of finished stages."""
    summary: dict[str, Any] = {}
    for stage in stages:
        if stage.name in SUMMARY_STAGES and stage.status == StageStatus.SUCCEEDED:
            summary.update({k: v for k, v in stage.metrics.items() if k != "seconds"})
    return summary


def _pipeline_order(stage: Stage) -> tuple[int, int, int]:
    return STAGES.index(stage.name), stage.camera or 0, stage.frame_start or 0


def job_out(job: Job, storage: Storage) -> JobOut:
    return JobOut(
        id=job.id,
        night_id=job.night_id,
        status=job.status,
        error=job.error,
        progress=job_progress(job.stages),
        params=job.params,
        created_at=job.created_at,
        submitted_at=job.submitted_at,
        started_at=job.started_at,
        finished_at=job.finished_at,
        files=[file_out(job, f, storage) for f in job.files],
        stages=[StageOut.model_validate(s) for s in sorted(job.stages, key=_pipeline_order)],
        summary=job_summary(job.stages),
    )
