"""Server-rendered pages: the upload form, a job's page and the admin page.

The pages hold no data themselves: their scripts call the REST API with the token
the user typed (kept in the browser's localStorage).
"""

from __future__ import annotations

import uuid
from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse
from fastapi.templating import Jinja2Templates

from pipeline.graph import STAGE_NAMES

templates = Jinja2Templates(directory=Path(__file__).resolve().parent.parent / "templates")
router = APIRouter(include_in_schema=False)


@router.get("/", response_class=HTMLResponse)
def upload_page(request: Request) -> HTMLResponse:
    return templates.TemplateResponse(request, "upload.html", {"title": "Upload a recording"})


@router.get("/jobs/{job_id}", response_class=HTMLResponse)
def job_page(request: Request, job_id: uuid.UUID) -> HTMLResponse:
    return templates.TemplateResponse(request, "job.html", {"title": "Job", "job_id": str(job_id)})


@router.get("/admin", response_class=HTMLResponse)
def admin_page(request: Request) -> HTMLResponse:
    context = {"title": "Admin", "stages": STAGE_NAMES}
    return templates.TemplateResponse(request, "admin.html", context)
