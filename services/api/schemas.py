"""Request and response bodies of the REST API (pydantic; separate from the ORM models)."""

from __future__ import annotations

import datetime as dt
import re
import uuid
from typing import Annotated, Any, Literal
from zoneinfo import ZoneInfo

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    WithJsonSchema,
    field_validator,
    model_validator,
)

from pipeline.graph import STAGE_NAMES
from pipeline.night import check_start_time, check_time_zone
from pipeline.params import MAX_SEPARATION_M

CONTROL_CHARS = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")
#: Bidirectional controls: they make "evil\u202egpj.mp4" read as "evilmp4.jpg".
BIDI_CONTROLS = re.compile("[\u061c\u200e\u200f\u202a-\u202e\u2066-\u2069]")
FILENAME_FORBIDDEN = re.compile(r"[\x00-\x1f\x7f/\\]")


def _no_control_chars(value: str) -> str:
    if CONTROL_CHARS.search(value):
        raise ValueError("must not contain control characters")
    return value


def _single_line(value: str) -> str:
    if "\n" in value or "\t" in value:
        raise ValueError("must be a single line")
    if BIDI_CONTROLS.search(value):
        raise ValueError("must not contain bidirectional control characters")
    return _no_control_chars(value).strip()


def _safe_filename(value: str) -> str:
    if (
        FILENAME_FORBIDDEN.search(value)
        or not value.isprintable()
        or value.strip() in ("", ".", "..")
    ):
        raise ValueError(
            f"file name {value!r} must be a plain name of printable characters: no folders, "
            "'/', '\\', '..', control or bidirectional characters"
        )
    return value


Line = Annotated[str, AfterValidator(_single_line)]
Text = Annotated[str, AfterValidator(_no_control_chars)]
FileName = Annotated[str, Field(min_length=1, max_length=255), AfterValidator(_safe_filename)]


def _known_stage(value: str) -> str:
    if value not in STAGE_NAMES:
        raise ValueError(f"unknown stage {value!r}; stages: {', '.join(STAGE_NAMES)}")
    return value


#: A stage of the graph (`pipeline.graph.STAGE_NAMES`, never spelled out here).
StageName = Annotated[
    str,
    AfterValidator(_known_stage),
    WithJsonSchema({"type": "string", "enum": list(STAGE_NAMES)}),
]

FIRST_DATE = dt.date(2000, 1, 1)


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


# -- nights ------------------------------------------------------------------------------


class NightCreate(Strict):
    """A recording session: where, when, and how the two cameras were set up."""

    site: Line = Field(min_length=1, max_length=200, examples=["Congaree, Weston Lake loop"])
    date: dt.date = Field(description="local date the recording started")
    latitude: float | None = Field(default=None, ge=-90, le=90)
    longitude: float | None = Field(default=None, ge=-180, le=180)
    separation_m: float = Field(
        gt=0,
        le=MAX_SEPARATION_M,
        description="measured distance between the two cameras, metres",
        examples=[1.5],
    )
    height_m: float | None = Field(default=None, ge=0, le=100, description="camera height, metres")
    notes: Text = Field(default="", max_length=5000)
    time_zone: Line | None = Field(
        default=None,
        max_length=64,
        description="IANA time zone of the site; the cameras' clocks show local time there "
        "when camera_clock is 'local'",
        examples=["America/New_York"],
    )
    camera_clock: Literal["local", "utc"] = Field(
        default="local",
        description="how the videos' creation_time is written: the cameras' local wall-clock "
        "time (GoPro) or UTC",
    )
    start_time: dt.datetime | None = Field(
        default=None,
        description="when camera 1's first frame was recorded, ISO 8601 (without an offset: "
        "local time in time_zone); overrides the videos' creation time",
    )
    camera_model: Line | None = Field(default=None, max_length=100, examples=["GoPro Max"])

    @field_validator("date")
    @classmethod
    def _plausible_date(cls, value: dt.date) -> dt.date:
        tomorrow = dt.datetime.now(dt.UTC).date() + dt.timedelta(days=1)
        if not FIRST_DATE <= value <= tomorrow:
            raise ValueError(f"date must be between {FIRST_DATE} and {tomorrow}")
        return value

    @field_validator("time_zone")
    @classmethod
    def _known_zone(cls, value: str | None) -> str | None:
        return None if value is None else check_time_zone(value)

    @field_validator("start_time")
    @classmethod
    def _plausible_start(cls, value: dt.datetime | None) -> dt.datetime | None:
        tomorrow = dt.datetime.now(dt.UTC).date() + dt.timedelta(days=2)
        if value is not None and not FIRST_DATE <= value.date() <= tomorrow:
            raise ValueError(f"start_time must be between {FIRST_DATE} and {tomorrow}")
        return value

    @model_validator(mode="after")
    def _placeable_start(self) -> NightCreate:
        check_start_time(self.start_time, self.time_zone)
        if self.start_time is not None and self.start_time.tzinfo is None:
            # Wall-clock time at the site: stored as the instant it names (a naive value
            # would be read back as UTC from the timestamptz column).
            assert self.time_zone is not None
            self.start_time = self.start_time.replace(tzinfo=ZoneInfo(self.time_zone))
        return self


class JobBrief(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: uuid.UUID
    status: str
    created_at: dt.datetime


class NightOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: uuid.UUID
    site: str
    date: dt.date
    latitude: float | None
    longitude: float | None
    separation_m: float
    height_m: float | None
    notes: str
    time_zone: str | None = None
    camera_clock: str = "local"
    start_time: dt.datetime | None = None
    camera_model: str | None = None
    created_at: dt.datetime
    jobs: list[JobBrief] = []


# -- jobs and files ----------------------------------------------------------------------


class FileDeclaration(Strict):
    """One chapter file of one camera, declared before it is uploaded."""

    camera: int = Field(description="1 or 2", examples=[1])
    chapter: int = Field(ge=0, le=998, description="0-based position in the camera's recording")
    filename: FileName = Field(examples=["GS010042.mp4"])
    size: int = Field(gt=0, description="bytes")
    sha256: str | None = Field(
        default=None,
        description="hex SHA-256 of the whole file, checked if given (optional: the parts' "
        "checksums are recorded while uploading)",
        examples=["0" * 64],
    )

    @field_validator("camera")
    @classmethod
    def _known_camera(cls, value: int) -> int:
        if value not in (1, 2):
            raise ValueError(f"unknown camera {value}: cameras are 1 and 2")
        return value

    @field_validator("sha256")
    @classmethod
    def _hex_digest(cls, value: str | None) -> str | None:
        if value is None:
            return None
        if not re.fullmatch(r"[0-9a-fA-F]{64}", value):
            raise ValueError("sha256 must be 64 hexadecimal digits")
        return value.lower()


class JobCreate(Strict):
    """A stereo pair to process: each camera's chapter files, in order from 0."""

    night_id: uuid.UUID | None = Field(default=None, description="an existing night")
    night: NightCreate | None = Field(
        default=None, description="or a new night, created with the job (atomically)"
    )
    files: list[FileDeclaration] = Field(min_length=2, max_length=2 * 999)
    params: dict[str, Any] | None = Field(
        default=None,
        description="parameter overrides, deep-merged into the defaults (ProcessParams)",
    )

    @model_validator(mode="after")
    def _one_night(self) -> JobCreate:
        if (self.night_id is None) == (self.night is None):
            raise ValueError("give either night_id (an existing night) or night (a new one)")
        return self

    @model_validator(mode="after")
    def _chapters_complete(self) -> JobCreate:
        for camera in (1, 2):
            chapters = sorted(f.chapter for f in self.files if f.camera == camera)
            if not chapters:
                raise ValueError(f"camera {camera} has no chapter files")
            if chapters != list(range(len(chapters))):
                raise ValueError(
                    f"camera {camera}: chapters must be numbered 0, 1, 2, … without gaps or "
                    f"repeats; got {', '.join(map(str, chapters))}"
                )
        return self


class FileOut(BaseModel):
    """A declared file, its upload state and how to upload it."""

    camera: int
    chapter: int
    filename: str
    size: int
    sha256: str | None
    checksum: str | None = Field(
        description="SHA-256 of the parts' SHA-256 digests (S3's checksum of checksums)"
    )
    upload_state: str
    method: Literal["s3-multipart", "stream"]
    part_size: int = Field(description="bytes per part (multipart) or per PUT request (stream)")
    part_count: int
    upload_url: str = Field(description="stream: PUT here; multipart: POST {url}/parts to sign")


class FileStatus(FileOut):
    received_bytes: int
    uploaded_parts: list[int] = Field(description="multipart: part numbers already stored")


class PartsRequest(Strict):
    part_numbers: list[int] = Field(min_length=1, max_length=100)
    checksums_sha256: list[str] | None = Field(
        default=None,
        description="base64 SHA-256 of each part, in the order of part_numbers: signed "
        "into the URLs (send it as x-amz-checksum-sha256; S3 refuses a different body)",
    )

    @field_validator("part_numbers")
    @classmethod
    def _in_range(cls, numbers: list[int]) -> list[int]:
        if any(not 1 <= n <= 10_000 for n in numbers):
            raise ValueError("part numbers run from 1 to 10000")
        return numbers

    @model_validator(mode="after")
    def _one_checksum_per_part(self) -> PartsRequest:
        if self.checksums_sha256 is not None and len(self.checksums_sha256) != len(
            self.part_numbers
        ):
            raise ValueError("checksums_sha256 needs one checksum per part number")
        return self


class PartUrl(BaseModel):
    number: int
    url: str


class PartsSigned(BaseModel):
    part_size: int
    part_count: int
    expires_s: int
    parts: list[PartUrl]


class StageOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    key: str
    name: str
    camera: int | None
    frame_start: int | None
    frame_stop: int | None
    status: str
    attempt: int
    progress: float
    started_at: dt.datetime | None
    finished_at: dt.datetime | None
    heartbeat_at: dt.datetime | None = Field(description="last sign of life while running")
    stalled_at: dt.datetime | None = Field(
        description="when the stage was last re-queued because its worker fell silent"
    )
    metrics: dict[str, Any]
    warnings: list[str]
    error: str | None


class JobOut(BaseModel):
    id: uuid.UUID
    night_id: uuid.UUID
    site: str
    date: dt.date
    team: str
    status: str
    error: str | None
    progress: float = Field(description="fraction of the pipeline done, 0–1")
    params: dict[str, Any]
    created_at: dt.datetime
    submitted_at: dt.datetime | None
    started_at: dt.datetime | None
    finished_at: dt.datetime | None
    files: list[FileOut]
    stages: list[StageOut]
    summary: dict[str, Any] = Field(
        description="the run summary (pipeline.summary) of the stages finished so far"
    )


class LinkRequest(Strict):
    name: str | None = Field(
        default=None, description="an artifact's name; none: the zip of all the results"
    )


class LinkOut(BaseModel):
    url: str = Field(description="works without a token until it expires")
    expires_s: int


class ArtifactOut(BaseModel):
    name: str
    size: int
    content_type: str
    stage: str
    category: Literal["result", "intermediate"]
    url: str = Field(description="short-lived download link (no token needed)")


# -- admin -------------------------------------------------------------------------------


class TeamCreate(Strict):
    name: Line = Field(min_length=1, max_length=100)
    expires_in_days: float | None = Field(default=None, gt=0, le=3650)


class TokenCreate(Strict):
    label: Line = Field(default="", max_length=100)
    expires_in_days: float | None = Field(default=None, gt=0, le=3650)


class TokenOut(BaseModel):
    id: uuid.UUID
    label: str
    created_at: dt.datetime
    expires_at: dt.datetime | None
    revoked_at: dt.datetime | None
    state: str = Field(description="valid, valid until …, expired … or revoked …")


class TeamOut(BaseModel):
    id: uuid.UUID
    name: str
    created_at: dt.datetime
    tokens: list[TokenOut]


class IssuedToken(BaseModel):
    team_id: uuid.UUID
    team: str
    token: TokenOut
    secret: str = Field(description="the bearer token: shown this once, never stored")


class RerunRequest(Strict):
    from_stage: StageName | None = Field(
        default=None, description="default: the first stage that has not succeeded"
    )
    params: dict[str, Any] | None = Field(default=None, description="parameter overrides")


class RerunOut(BaseModel):
    job_id: uuid.UUID
    from_stage: str
    status: str


class AdminJobOut(BaseModel):
    id: uuid.UUID
    team: str
    night_id: uuid.UUID
    site: str
    date: dt.date
    status: str
    error: str | None
    created_at: dt.datetime
    updated_at: dt.datetime
    stalled_at: dt.datetime | None = Field(
        description="set while the job's work is stalled (a worker fell silent)"
    )


class ParamOut(BaseModel):
    path: str = Field(description="dotted name, as in params overrides", examples=["sync.window_s"])
    description: str
    type: str
    default: Any
