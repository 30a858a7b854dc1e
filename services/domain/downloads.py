"""Downloads of a job's artifacts: presigned S3 URLs, or signed links streamed by the API."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import PurePosixPath

from pipeline.artifacts import CALIBRATION_JSON, CAMERAS, REPORT_DIR, TRAJECTORIES_CSV, flashes_name
from services.core.models import Artifact, Job
from services.core.security import sign_payload, verify_payload
from services.core.settings import Settings
from services.core.storage import Disposition, Storage
from services.domain.errors import Forbidden, NotFound

RESULTS = {TRAJECTORIES_CSV, CALIBRATION_JSON, *(flashes_name(c) for c in CAMERAS)}


@dataclass(frozen=True)
class Stream:
    """An object to send through the API."""

    chunks: Iterator[bytes]
    size: int
    filename: str
    content_type: str
    disposition: Disposition


def is_result(name: str) -> bool:
    """Whether an artifact is one of the CONTRACT outputs (the rest are intermediates)."""
    return name in RESULTS or name.startswith(f"{REPORT_DIR}/")


def _disposition(content_type: str) -> Disposition:
    return "inline" if content_type.startswith("image/") else "attachment"


def _direct_url(settings: Settings, storage: Storage, artifact: Artifact) -> str | None:
    filename = PurePosixPath(artifact.name).name
    return storage.download_url(
        artifact.storage_key,
        settings.download_url_expires_s,
        filename,
        _disposition(artifact.content_type),
    )


def download_url(
    settings: Settings, storage: Storage, artifact: Artifact, signed_route: str
) -> str:
    """A link that works without a token until it expires: presigned by the store, or a
    signed token under `signed_route` (the API's route for `signed_download`)."""
    direct = _direct_url(settings, storage, artifact)
    if direct is not None:
        return direct
    filename = PurePosixPath(artifact.name).name
    payload = {"key": artifact.storage_key, "name": filename, "type": artifact.content_type}
    expires = settings.download_url_expires_s
    signed = sign_payload(payload, settings.signing_key(), expires)
    return f"{signed_route}/{signed}"


def find_artifact(job: Job, name: str) -> Artifact:
    for artifact in job.artifacts:
        if artifact.name == name:
            return artifact
    raise NotFound(f"job {job.id} has no artifact {name!r}")


def _stream(storage: Storage, key: str, filename: str, content_type: str) -> Stream:
    size = storage.size(key)
    if size is None:
        raise NotFound(f"{filename} is no longer stored")
    return Stream(storage.iter_bytes(key), size, filename, content_type, _disposition(content_type))


def artifact_download(settings: Settings, storage: Storage, artifact: Artifact) -> str | Stream:
    """A presigned URL to redirect to, or the artifact to stream through the API."""
    direct = _direct_url(settings, storage, artifact)
    if direct is not None:
        return direct
    filename = PurePosixPath(artifact.name).name
    return _stream(storage, artifact.storage_key, filename, artifact.content_type)


def signed_download(settings: Settings, storage: Storage, token: str) -> Stream:
    """The object a link from `download_url` names, if the link is valid."""
    payload = verify_payload(token, settings.signing_key())
    if payload is None or not {"key", "name", "type"} <= payload.keys():
        raise Forbidden("this download link is invalid or has expired")
    return _stream(storage, payload["key"], payload["name"], payload["type"])
