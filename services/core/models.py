"""SQLAlchemy 2 ORM models: the authoritative state of teams, nights, jobs and stages.

Alembic migrations in ``migrations/`` build exactly this schema (a test compares them).
Identifiers are random UUIDs so that URLs cannot be guessed.
"""

from __future__ import annotations

import uuid
from datetime import date, datetime
from enum import StrEnum
from typing import Any, ClassVar

from sqlalchemy import (
    BigInteger,
    CheckConstraint,
    Date,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Text,
    UniqueConstraint,
    func,
)
from sqlalchemy.dialects.postgresql import JSONB
from sqlalchemy.orm import DeclarativeBase, Mapped, MappedColumn, mapped_column, relationship

NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map: ClassVar = {dict[str, Any]: JSONB, list[str]: JSONB}


class JobStatus(StrEnum):
    CREATED = "created"
    UPLOADING = "uploading"
    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"


class StageStatus(StrEnum):
    PENDING = "pending"
    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"


class UploadState(StrEnum):
    PENDING = "pending"
    UPLOADING = "uploading"
    UPLOADED = "uploaded"


def _in(column: str, values: type[StrEnum]) -> str:
    return f"{column} IN ({', '.join(repr(v.value) for v in values)})"


def _now() -> MappedColumn[datetime]:
    return mapped_column(DateTime(timezone=True), server_default=func.now())


class Team(Base):
    __tablename__ = "teams"

    id: Mapped[uuid.UUID] = mapped_column(primary_key=True, default=uuid.uuid4)
    name: Mapped[str] = mapped_column(String(100), unique=True)
    created_at: Mapped[datetime] = _now()

    tokens: Mapped[list[TeamToken]] = relationship(
        back_populates="team", order_by="TeamToken.created_at"
    )


class TeamToken(Base):
    """A team's bearer token (only its hash): several may be valid at once (rotation)."""

    __tablename__ = "team_tokens"

    id: Mapped[uuid.UUID] = mapped_column(primary_key=True, default=uuid.uuid4)
    team_id: Mapped[uuid.UUID] = mapped_column(ForeignKey("teams.id"), index=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    label: Mapped[str] = mapped_column(String(100), default="")
    created_at: Mapped[datetime] = _now()
    expires_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    revoked_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))

    team: Mapped[Team] = relationship(back_populates="tokens")


class Night(Base):
    __tablename__ = "nights"
    __table_args__ = (
        CheckConstraint("separation_m > 0", name="separation_positive"),
        CheckConstraint("latitude BETWEEN -90 AND 90", name="latitude_range"),
        CheckConstraint("longitude BETWEEN -180 AND 180", name="longitude_range"),
    )

    id: Mapped[uuid.UUID] = mapped_column(primary_key=True, default=uuid.uuid4)
    team_id: Mapped[uuid.UUID] = mapped_column(ForeignKey("teams.id"), index=True)
    site: Mapped[str] = mapped_column(String(200))
    date: Mapped[date] = mapped_column(Date)
    latitude: Mapped[float | None] = mapped_column(Float)
    longitude: Mapped[float | None] = mapped_column(Float)
    separation_m: Mapped[float] = mapped_column(Float)
    height_m: Mapped[float | None] = mapped_column(Float)
    notes: Mapped[str] = mapped_column(Text, default="")
    #: IANA time zone of the site (and of the cameras' clocks when camera_clock is local).
    time_zone: Mapped[str | None] = mapped_column(String(64))
    #: How the videos' creation_time is written: "local" (GoPro) or "utc".
    camera_clock: Mapped[str] = mapped_column(String(8), default="local", server_default="local")
    #: When camera 1's frame 0 was recorded, if the team gives it (overrides the videos).
    start_time: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    camera_model: Mapped[str | None] = mapped_column(String(100))
    created_at: Mapped[datetime] = _now()

    team: Mapped[Team] = relationship()
    jobs: Mapped[list[Job]] = relationship(back_populates="night", order_by="Job.created_at")


class Job(Base):
    __tablename__ = "jobs"
    __table_args__ = (CheckConstraint(_in("status", JobStatus), name="status"),)

    id: Mapped[uuid.UUID] = mapped_column(primary_key=True, default=uuid.uuid4)
    night_id: Mapped[uuid.UUID] = mapped_column(ForeignKey("nights.id"), index=True)
    status: Mapped[str] = mapped_column(String(16), default=JobStatus.CREATED)
    params: Mapped[dict[str, Any]]
    #: The run summary of the stages finished so far (`pipeline.summary`).
    summary: Mapped[dict[str, Any]] = mapped_column(default=dict, server_default="{}")
    error: Mapped[str | None] = mapped_column(Text)
    created_at: Mapped[datetime] = _now()
    submitted_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    updated_at: Mapped[datetime] = mapped_column(
        DateTime(timezone=True), server_default=func.now(), onupdate=func.now()
    )

    night: Mapped[Night] = relationship(back_populates="jobs")
    files: Mapped[list[InputFile]] = relationship(
        back_populates="job", order_by="(InputFile.camera, InputFile.chapter)"
    )
    stages: Mapped[list[Stage]] = relationship(back_populates="job", order_by="Stage.id")
    artifacts: Mapped[list[Artifact]] = relationship(back_populates="job", order_by="Artifact.name")


class InputFile(Base):
    __tablename__ = "input_files"
    __table_args__ = (
        UniqueConstraint("job_id", "camera", "chapter"),
        CheckConstraint("camera IN (1, 2)", name="camera"),
        CheckConstraint("chapter >= 0", name="chapter"),
        CheckConstraint("size > 0", name="size"),
        CheckConstraint(_in("upload_state", UploadState), name="upload_state"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[uuid.UUID] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"))
    camera: Mapped[int] = mapped_column(Integer)
    chapter: Mapped[int] = mapped_column(Integer)
    filename: Mapped[str] = mapped_column(String(255))
    size: Mapped[int] = mapped_column(BigInteger)
    #: SHA-256 of the whole file, if the team declared it (the page does not: it hashes
    #: per part while uploading, see `part_checksums`).
    sha256: Mapped[str | None] = mapped_column(String(64))
    #: Hex SHA-256 of each part (``"1"``, ``"2"``, …) received so far: signed into the
    #: presigned S3 URL (S3 checks it), or computed by the API on the stream path.
    part_checksums: Mapped[dict[str, Any]] = mapped_column(default=dict, server_default="{}")
    #: SHA-256 of the concatenated part digests (`services.core.checksums`), once uploaded.
    checksum: Mapped[str | None] = mapped_column(String(64))
    storage_key: Mapped[str] = mapped_column(String(512))
    upload_state: Mapped[str] = mapped_column(String(16), default=UploadState.PENDING)
    upload_id: Mapped[str | None] = mapped_column(String(1024))
    part_size: Mapped[int] = mapped_column(BigInteger)
    uploaded_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))

    job: Mapped[Job] = relationship(back_populates="files")


class Stage(Base):
    __tablename__ = "stages"
    __table_args__ = (
        UniqueConstraint("job_id", "key"),
        CheckConstraint(_in("status", StageStatus), name="status"),
        CheckConstraint("progress BETWEEN 0 AND 1", name="progress"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[uuid.UUID] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"))
    key: Mapped[str] = mapped_column(String(64))
    name: Mapped[str] = mapped_column(String(16))
    camera: Mapped[int | None] = mapped_column(Integer)
    frame_start: Mapped[int | None] = mapped_column(BigInteger)
    frame_stop: Mapped[int | None] = mapped_column(BigInteger)
    status: Mapped[str] = mapped_column(String(16), default=StageStatus.PENDING)
    attempt: Mapped[int] = mapped_column(Integer, default=0)
    deliveries: Mapped[int] = mapped_column(Integer, default=0)
    queue_token: Mapped[str | None] = mapped_column(String(32))
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    queued_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    #: Last sign of life of the worker running the stage (`services.worker.heartbeat`).
    heartbeat_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    #: When the sweeper last re-queued the stage because its heartbeat had stopped.
    stalled_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    metrics: Mapped[dict[str, Any]] = mapped_column(default=dict)
    warnings: Mapped[list[str]] = mapped_column(default=list)
    error: Mapped[str | None] = mapped_column(Text)

    job: Mapped[Job] = relationship(back_populates="stages")


class Artifact(Base):
    __tablename__ = "artifacts"
    __table_args__ = (UniqueConstraint("job_id", "name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[uuid.UUID] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"))
    stage_id: Mapped[int] = mapped_column(ForeignKey("stages.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(255))
    storage_key: Mapped[str] = mapped_column(String(512))
    size: Mapped[int] = mapped_column(BigInteger)
    content_type: Mapped[str] = mapped_column(String(100))
    created_at: Mapped[datetime] = _now()

    job: Mapped[Job] = relationship(back_populates="artifacts")


Index("ix_jobs_status_updated", Job.status, Job.updated_at)
#: The sweeper's query: running stages by heartbeat.
Index("ix_stages_status_heartbeat", Stage.status, Stage.heartbeat_at)
