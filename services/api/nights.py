"""Nights: a team's recording sessions."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from services.api.schemas import NightCreate, NightOut
from services.core.models import Night, Team


def create_night(session: Session, team: Team, body: NightCreate) -> Night:
    night = Night(team_id=team.id, **body.model_dump())
    session.add(night)
    session.commit()
    return night


def list_nights(session: Session, team: Team) -> list[Night]:
    query = (
        select(Night).where(Night.team_id == team.id).order_by(Night.date.desc(), Night.created_at)
    )
    return list(session.scalars(query))


def night_out(night: Night) -> NightOut:
    return NightOut.model_validate(night)
