"""Nights: a team's recording sessions."""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session

from pipeline.night import NightInfo
from services.core.models import Night, Team
from services.domain.repositories import nights


def create_night(session: Session, team: Team, fields: dict[str, Any]) -> Night:
    """Record a night (site, date, location, camera separation and height); commits."""
    night = Night(team_id=team.id, **fields)
    session.add(night)
    session.commit()
    return night


def list_nights(session: Session, team: Team) -> list[Night]:
    return nights.of_team(session, team.id)


def night_info(night: Night) -> NightInfo:
    """What the pipeline knows of a night (`pipeline.night.NightInfo`), from its row."""
    return NightInfo(
        site=night.site,
        date=night.date,
        latitude=night.latitude,
        longitude=night.longitude,
        time_zone=night.time_zone,
        camera_clock="utc" if night.camera_clock == "utc" else "local",
        start_time=night.start_time,
        camera_model=night.camera_model,
        notes=night.notes or "",
    )
