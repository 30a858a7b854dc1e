"""``/api/v1/downloads``: signed, expiring links (local storage has no presigned URLs)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import Response, StreamingResponse

from services.api.deps import SessionDep, SettingsDep, StorageDep
from services.domain import downloads
from services.domain.downloads import Stream

router = APIRouter(prefix="/downloads", tags=["jobs"])


def stream_response(stream: Stream) -> StreamingResponse:
    headers = {"Content-Disposition": f'{stream.disposition}; filename="{stream.filename}"'}
    if stream.size is not None:
        headers["Content-Length"] = str(stream.size)
    return StreamingResponse(stream.chunks, media_type=stream.content_type, headers=headers)


@router.get("/{token}", response_class=Response, responses={200: {"description": "the file"}})
def download(
    token: str, settings: SettingsDep, storage: StorageDep, session: SessionDep
) -> Response:
    """The file (or the zip of a job's results) a signed link names, while it is valid."""
    return stream_response(downloads.signed_download(settings, storage, session, token))
