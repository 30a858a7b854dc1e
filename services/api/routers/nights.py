"""``/api/v1/nights``: a team's recording sessions."""

from __future__ import annotations

import uuid

from fastapi import APIRouter, status

from services.api import views
from services.api.deps import PrincipalDep, SessionDep, TeamDep
from services.api.schemas import NightCreate, NightOut
from services.domain import access, nights

router = APIRouter(prefix="/nights", tags=["nights"])


@router.post("", status_code=status.HTTP_201_CREATED)
def create_night(body: NightCreate, team: TeamDep, session: SessionDep) -> NightOut:
    """Record a night: site, date, location and the cameras' separation and height."""
    return views.night_out(nights.create_night(session, team, body.model_dump()))


@router.get("")
def list_nights(team: TeamDep, session: SessionDep) -> list[NightOut]:
    """The calling team's nights, latest first."""
    return [views.night_out(n) for n in nights.list_nights(session, team)]


@router.get("/{night_id}")
def get_night(night_id: uuid.UUID, principal: PrincipalDep, session: SessionDep) -> NightOut:
    """One night with its jobs."""
    return views.night_out(access.visible_night(session, principal, night_id))
