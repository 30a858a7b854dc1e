"""Downloads of a job's artifacts: presigned S3 URLs, or signed links streamed by the API.

Pages ask for a link when the user clicks (`POST /jobs/{id}/links`), so a page left
open for hours never offers an expired one; "download all" is a zip streamed by the
API (`services.domain.archive`) through a signed link: the job's results and report, and
a ``datapackage.json`` describing them (`pipeline.package`, the builder the CLI's
``--package`` uses), made from the night's row when the zip is asked for.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import PurePosixPath

from sqlalchemy.orm import Session

from pipeline.artifacts import CALIBRATION_JSON, DATAPACKAGE_JSON
from pipeline.package import PackageFile, csv_header, datapackage, is_package_file
from services.core.models import Artifact, Job
from services.core.security import sign_payload, verify_payload
from services.core.settings import Settings
from services.core.storage import Disposition, Storage
from services.domain.archive import ZipMember, zip_stream
from services.domain.errors import Forbidden, NotFound
from services.domain.nights import night_info
from services.domain.repositories import jobs


@dataclass(frozen=True)
class Stream:
    """An object to send through the API (`size` None: not known in advance)."""

    chunks: Iterator[bytes]
    size: int | None
    filename: str
    content_type: str
    disposition: Disposition


def is_result(name: str) -> bool:
    """Whether an artifact is a result (CSV, JSON, report); the rest are intermediates."""
    return is_package_file(name)


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


def archive_name(job: Job) -> str:
    """``firefly3d-<site>-<date>-<job>.zip``, the site reduced to safe characters."""
    site = re.sub(r"[^A-Za-z0-9]+", "-", job.night.site).strip("-")[:40] or "site"
    return f"firefly3d-{site}-{job.night.date}-{str(job.id)[:8]}.zip"


def result_members(storage: Storage, job: Job) -> list[ZipMember]:
    """The job's results (CSV, JSON, report) as zip members, read lazily from storage.

    A caller that wants more in the archive (e.g. generated metadata) appends members.
    """
    return [(a.name, _lazy(storage, a.storage_key)) for a in job.artifacts if is_result(a.name)]


def package_member(storage: Storage, job: Job) -> ZipMember:
    """``datapackage.json`` of the job's results, built when its turn in the zip comes."""

    def build() -> Iterator[bytes]:
        files = []
        calibration = None
        for artifact in job.artifacts:
            if not is_result(artifact.name):
                continue
            header: tuple[str, ...] = ()
            if artifact.name.endswith(".csv"):
                header = csv_header(next(iter(storage.iter_bytes(artifact.storage_key)), b""))
            elif artifact.name == CALIBRATION_JSON:
                calibration = json.loads(storage.read_bytes(artifact.storage_key))
            files.append(PackageFile(artifact.name, artifact.size, header))
        package = datapackage(
            files, night_info(job.night), calibration, job.summary, job.finished_at
        )
        yield (json.dumps(package, indent=2) + "\n").encode()

    return DATAPACKAGE_JSON, build()


def _lazy(storage: Storage, key: str) -> Iterable[bytes]:
    """The object's chunks, opened only when iterated (when its member is written)."""
    yield from storage.iter_bytes(key)


def archive_url(settings: Settings, job: Job, signed_route: str) -> str:
    """A link to the zip of the job's results that works without a token until it expires."""
    payload = {"archive": str(job.id), "name": archive_name(job)}
    signed = sign_payload(payload, settings.signing_key(), settings.download_url_expires_s)
    return f"{signed_route}/{signed}"


def signed_download(settings: Settings, storage: Storage, session: Session, token: str) -> Stream:
    """The object, or the results archive, a signed link names, if the link is valid."""
    payload = verify_payload(token, settings.signing_key())
    if payload is not None and {"archive", "name"} <= payload.keys():
        job = jobs.get(session, payload["archive"])
        if job is None:
            raise NotFound("this job no longer exists")
        members = [*result_members(storage, job), package_member(storage, job)]
        chunks = zip_stream(members, job.finished_at)
        return Stream(chunks, None, payload["name"], "application/zip", "attachment")
    if payload is None or not {"key", "name", "type"} <= payload.keys():
        raise Forbidden("this download link is invalid or has expired")
    return _stream(storage, payload["key"], payload["name"], payload["type"])


def link(settings: Settings, storage: Storage, job: Job, name: str | None, route: str) -> str:
    """A fresh link to the artifact `name`, or (None) to the zip of the job's results."""
    if name is None:
        return archive_url(settings, job, route)
    return download_url(settings, storage, find_artifact(job, name), route)
