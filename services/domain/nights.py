"""Nights: a team's recording sessions."""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session

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
