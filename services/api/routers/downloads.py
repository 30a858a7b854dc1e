"""``/api/v1/downloads``: signed, expiring links (local storage has no presigned URLs)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import Response

from services.api import artifacts
from services.api.deps import SettingsDep, StorageDep

router = APIRouter(prefix="/downloads", tags=["jobs"])


@router.get("/{token}", response_class=Response, responses={200: {"description": "the file"}})
def download(token: str, settings: SettingsDep, storage: StorageDep) -> Response:
    """The file a link from the artifact list names, while the link is valid."""
    return artifacts.signed_download(settings, storage, token)
