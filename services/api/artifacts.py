"""Downloads of a job's artifacts: presigned S3 URLs, or signed links streamed by the API."""

from __future__ import annotations

from pathlib import PurePosixPath

from fastapi import HTTPException, status
from fastapi.responses import RedirectResponse, Response, StreamingResponse

from pipeline.artifacts import CALIBRATION_JSON, CAMERAS, REPORT_DIR, TRAJECTORIES_CSV, flashes_name
from services.api.jobs import API_PREFIX
from services.api.schemas import ArtifactOut
from services.core.models import Artifact, Job
from services.core.security import sign_payload, verify_payload
from services.core.settings import Settings
from services.core.storage import Disposition, Storage

RESULTS = {TRAJECTORIES_CSV, CALIBRATION_JSON, *(flashes_name(c) for c in CAMERAS)}


def is_result(name: str) -> bool:
    """Whether an artifact is one of the CONTRACT outputs (the rest are intermediates)."""
    return name in RESULTS or name.startswith(f"{REPORT_DIR}/")


def _disposition(artifact: Artifact) -> Disposition:
    return "inline" if artifact.content_type.startswith("image/") else "attachment"


def download_url(settings: Settings, storage: Storage, artifact: Artifact) -> str:
    """A link that works without a token until it expires."""
    filename = PurePosixPath(artifact.name).name
    expires = settings.download_url_expires_s
    direct = storage.download_url(artifact.storage_key, expires, filename, _disposition(artifact))
    if direct is not None:
        return direct
    payload = {"key": artifact.storage_key, "name": filename, "type": artifact.content_type}
    signed = sign_payload(payload, settings.secret_key.get_secret_value(), expires)
    return f"{API_PREFIX}/downloads/{signed}"


def list_artifacts(settings: Settings, storage: Storage, job: Job) -> list[ArtifactOut]:
    stages = {s.id: s.name for s in job.stages}
    return [
        ArtifactOut(
            name=a.name,
            size=a.size,
            content_type=a.content_type,
            stage=stages.get(a.stage_id, ""),
            category="result" if is_result(a.name) else "intermediate",
            url=download_url(settings, storage, a),
        )
        for a in job.artifacts
    ]


def find_artifact(job: Job, name: str) -> Artifact:
    for artifact in job.artifacts:
        if artifact.name == name:
            return artifact
    raise HTTPException(status.HTTP_404_NOT_FOUND, f"job {job.id} has no artifact {name!r}")


def _stream(
    storage: Storage, key: str, filename: str, content_type: str, disposition: Disposition
) -> Response:
    headers = {"Content-Disposition": f'{disposition}; filename="{filename}"'}
    size = storage.size(key)
    if size is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"{filename} is no longer stored")
    headers["Content-Length"] = str(size)
    return StreamingResponse(storage.iter_bytes(key), media_type=content_type, headers=headers)


def artifact_response(settings: Settings, storage: Storage, artifact: Artifact) -> Response:
    """A redirect to a presigned URL, or the artifact streamed through the API."""
    url = download_url(settings, storage, artifact)
    if not url.startswith(API_PREFIX):
        return RedirectResponse(url, status.HTTP_307_TEMPORARY_REDIRECT)
    filename = PurePosixPath(artifact.name).name
    return _stream(
        storage, artifact.storage_key, filename, artifact.content_type, _disposition(artifact)
    )


def signed_download(settings: Settings, storage: Storage, token: str) -> Response:
    """Stream the object a link from `download_url` names, if the link is valid."""
    payload = verify_payload(token, settings.secret_key.get_secret_value())
    if payload is None or not {"key", "name", "type"} <= payload.keys():
        raise HTTPException(
            status.HTTP_403_FORBIDDEN, "this download link is invalid or has expired"
        )
    disposition: Disposition = "inline" if payload["type"].startswith("image/") else "attachment"
    return _stream(storage, payload["key"], payload["name"], payload["type"], disposition)
