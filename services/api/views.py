"""Response bodies (`services.api.schemas`) built from domain objects."""

from __future__ import annotations

from datetime import datetime

from pipeline import graph
from services.api.schemas import (
    AdminJobOut,
    ArtifactOut,
    FileOut,
    FileStatus,
    IssuedToken,
    JobOut,
    NightOut,
    PartsSigned,
    PartUrl,
    StageOut,
    TeamOut,
    TokenOut,
)
from services.core.models import InputFile, Job, Night, Stage, Team, TeamToken
from services.core.settings import Settings
from services.core.storage import Storage
from services.domain import downloads, teams, workflow
from services.domain.teams import Issued
from services.domain.uploads import SignedParts, UploadProgress, part_count

API_PREFIX = "/api/v1"
#: The route of signed download links (`services.api.routers.downloads`).
DOWNLOADS = f"{API_PREFIX}/downloads"


def night_out(night: Night) -> NightOut:
    return NightOut.model_validate(night)


def file_out(job: Job, file: InputFile, storage: Storage) -> FileOut:
    return FileOut(
        camera=file.camera,
        chapter=file.chapter,
        filename=file.filename,
        size=file.size,
        sha256=file.sha256,
        checksum=file.checksum,
        upload_state=file.upload_state,
        method=storage.upload_mode,
        part_size=file.part_size,
        part_count=part_count(file),
        upload_url=f"{API_PREFIX}/jobs/{job.id}/files/{file.camera}/{file.chapter}",
    )


def file_status(upload: UploadProgress, storage: Storage) -> FileStatus:
    return FileStatus(
        **file_out(upload.job, upload.file, storage).model_dump(),
        received_bytes=upload.received_bytes,
        uploaded_parts=upload.uploaded_parts,
    )


def parts_signed(signed: SignedParts) -> PartsSigned:
    return PartsSigned(
        part_size=signed.part_size,
        part_count=signed.part_count,
        expires_s=signed.expires_s,
        parts=[PartUrl(number=n, url=u) for n, u in sorted(signed.urls.items())],
    )


def _pipeline_order(stage: Stage) -> tuple[int, int, int]:
    return graph.position(workflow.unit_of(stage))


def job_out(job: Job, storage: Storage) -> JobOut:
    return JobOut(
        id=job.id,
        night_id=job.night_id,
        site=job.night.site,
        date=job.night.date,
        team=job.night.team.name,
        status=job.status,
        error=job.error,
        progress=workflow.progress(job.stages),
        params=job.params,
        created_at=job.created_at,
        submitted_at=job.submitted_at,
        started_at=job.started_at,
        finished_at=job.finished_at,
        files=[file_out(job, f, storage) for f in job.files],
        stages=[StageOut.model_validate(s) for s in sorted(job.stages, key=_pipeline_order)],
        summary=job.summary,
    )


def artifacts_out(settings: Settings, storage: Storage, job: Job) -> list[ArtifactOut]:
    stages = {s.id: s.name for s in job.stages}
    return [
        ArtifactOut(
            name=a.name,
            size=a.size,
            content_type=a.content_type,
            stage=stages.get(a.stage_id, ""),
            category="result" if downloads.is_result(a.name) else "intermediate",
            url=downloads.download_url(settings, storage, a, DOWNLOADS),
        )
        for a in job.artifacts
    ]


def token_out(token: TeamToken) -> TokenOut:
    return TokenOut(
        id=token.id,
        label=token.label,
        created_at=token.created_at,
        expires_at=token.expires_at,
        revoked_at=token.revoked_at,
        state=teams.token_state(token),
    )


def team_out(team: Team) -> TeamOut:
    return TeamOut(
        id=team.id,
        name=team.name,
        created_at=team.created_at,
        tokens=[token_out(t) for t in team.tokens],
    )


def issued_out(issued: Issued) -> IssuedToken:
    return IssuedToken(
        team_id=issued.team.id,
        team=issued.team.name,
        token=token_out(issued.token),
        secret=issued.secret,
    )


def admin_job_out(job: Job, night: Night, team: Team, stalled_at: datetime | None) -> AdminJobOut:
    return AdminJobOut(
        id=job.id,
        team=team.name,
        night_id=night.id,
        site=night.site,
        date=night.date,
        status=job.status,
        error=job.error,
        created_at=job.created_at,
        updated_at=job.updated_at,
        stalled_at=stalled_at,
    )
