"""``/api/v1/admin``: every team's jobs, re-runs, teams and tokens (admin token)."""

from __future__ import annotations

import uuid
from typing import Annotated, Literal

from fastapi import APIRouter, Query

from services.api import views
from services.api.deps import AdminDep, SendDep, SessionDep, SettingsDep, StorageDep
from services.api.schemas import (
    AdminJobOut,
    IssuedToken,
    ParamOut,
    RerunOut,
    RerunRequest,
    TeamCreate,
    TeamOut,
    TokenCreate,
    TokenOut,
)
from services.core.models import JobStatus
from services.domain import admin, parameters, teams

router = APIRouter(prefix="/admin", tags=["admin"])


@router.get("/jobs")
def list_jobs(
    _: AdminDep,
    session: SessionDep,
    settings: SettingsDep,
    status: Annotated[
        JobStatus | Literal["stalled"] | None,
        Query(description="only jobs in this state; stalled: active jobs whose worker fell silent"),
    ] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> list[AdminJobOut]:
    """Jobs of every team, most recently changed first."""
    rows = admin.list_jobs(session, settings, status, limit)
    return [views.admin_job_out(*row) for row in rows]


@router.post("/jobs/{job_id}/rerun")
def rerun_job(
    job_id: uuid.UUID,
    body: RerunRequest,
    _: AdminDep,
    session: SessionDep,
    storage: StorageDep,
    send: SendDep,
) -> RerunOut:
    """Re-run a finished job from a stage (default: its first unfinished one).

    Earlier stages are not run again: their rows and artifacts are reused.
    """
    start = admin.rerun_job(session, storage, send, job_id, body.from_stage, body.params)
    return RerunOut(job_id=job_id, from_stage=start, status=JobStatus.QUEUED)


@router.post("/nights/{night_id}/rerun-failed")
def rerun_failed(
    night_id: uuid.UUID, _: AdminDep, session: SessionDep, storage: StorageDep, send: SendDep
) -> list[RerunOut]:
    """Re-run every failed job of a night from its first unfinished stage."""
    return [
        RerunOut(job_id=job_id, from_stage=start, status=JobStatus.QUEUED)
        for job_id, start in admin.rerun_failed(session, storage, send, night_id)
    ]


@router.get("/teams")
def list_teams(_: AdminDep, session: SessionDep) -> list[TeamOut]:
    """Every team with its tokens (never the secrets, which are not stored)."""
    return [views.team_out(t) for t in teams.list_teams(session)]


@router.post("/teams", status_code=201)
def create_team(body: TeamCreate, _: AdminDep, session: SessionDep) -> IssuedToken:
    """A new team and its first token (shown once)."""
    return views.issued_out(teams.create_team(session, body.name, body.expires_in_days))


@router.post("/teams/{team_id}/tokens", status_code=201)
def issue_token(
    team_id: uuid.UUID, body: TokenCreate, _: AdminDep, session: SessionDep
) -> IssuedToken:
    """A further token for a team (e.g. one per field laptop), shown once."""
    team = teams.find_team(session, team_id)
    return views.issued_out(teams.issue_token(session, team, body.label, body.expires_in_days))


@router.post("/teams/{team_id}/rotate", status_code=201)
def rotate_tokens(
    team_id: uuid.UUID, body: TokenCreate, _: AdminDep, session: SessionDep
) -> IssuedToken:
    """Revoke every token of a team and issue a new one (a leaked or lost token)."""
    team = teams.find_team(session, team_id)
    label = body.label or "rotated"
    return views.issued_out(teams.rotate(session, team, label, body.expires_in_days))


@router.post("/tokens/{token_id}/revoke")
def revoke_token(token_id: uuid.UUID, _: AdminDep, session: SessionDep) -> TokenOut:
    """Revoke a token; API processes stop accepting it within FIREFLY3D_AUTH_CACHE_S."""
    return views.token_out(teams.revoke_token(session, token_id))


@router.get("/params")
def list_params(_: AdminDep) -> list[ParamOut]:
    """Every processing parameter (dotted name for overrides, description, default)."""
    return [ParamOut(**vars(p)) for p in parameters.parameters()]
