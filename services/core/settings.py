"""Service configuration: one pydantic-settings class, read from ``FIREFLY3D_*`` variables.

Every variable is documented in ``.env.example``; `Settings` is the single source of the
defaults. The API receives its settings explicitly (``create_app(settings)``), the worker
and the CLI read them from the environment through `get_settings`.
"""

from __future__ import annotations

import tempfile
from functools import lru_cache
from pathlib import Path
from typing import Literal, Self

from pydantic import Field, SecretStr, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

GiB = 1 << 30
MiB = 1 << 20


class Settings(BaseSettings):
    """All settings of the API, the worker and the admin CLI."""

    model_config = SettingsConfigDict(env_prefix="FIREFLY3D_", env_file=None, extra="ignore")

    # --- state and messaging
    database_url: str = "postgresql+psycopg://postgres@127.0.0.1:5432/firefly3d"
    broker_url: str = "redis://127.0.0.1:6379/0"
    broker_key_prefix: str = Field(
        default="", description="prefix of every Redis key of the broker"
    )
    queue: str = "firefly3d"

    # --- object storage
    storage_backend: Literal["s3", "local"] = "local"
    local_storage_dir: Path = Path("var/storage")
    s3_endpoint_url: str | None = None
    s3_public_endpoint_url: str | None = Field(
        default=None,
        description="endpoint the browser reaches for presigned URLs (default: endpoint)",
    )
    s3_bucket: str = "firefly3d"
    s3_region: str = "us-east-1"
    s3_access_key_id: SecretStr | None = None
    s3_secret_access_key: SecretStr | None = None

    # --- access
    admin_token: SecretStr | None = None
    secret_key: SecretStr | None = Field(
        default=None,
        description="signs download links; required by the API, the same in all its processes",
    )
    api_workers: int = Field(default=2, ge=1, le=64, description="API processes of `serve`")
    auth_cache_s: float = Field(
        default=5.0, ge=0, description="an API process trusts a checked token this long"
    )
    auth_failures_limit: int = Field(
        default=20, ge=1, description="failed authentications per client and window"
    )
    auth_failures_window_s: float = Field(default=60.0, gt=0)

    # --- quotas per team (0: no limit)
    quota_job_bytes: int = Field(default=0, ge=0, description="declared bytes of one job")
    quota_night_bytes: int = Field(default=0, ge=0, description="declared bytes of one night")
    quota_active_jobs: int = Field(
        default=0, ge=0, description="jobs of one team queued or running at once"
    )

    # --- limits
    max_file_bytes: int = Field(default=64 * GiB, gt=0)
    max_chapters: int = Field(default=99, gt=0, le=999)
    min_part_bytes: int = Field(default=8 * MiB, ge=5 * MiB, le=5 * GiB)
    upload_url_expires_s: int = Field(default=3600, gt=0, le=7 * 24 * 3600)
    download_url_expires_s: int = Field(default=300, gt=0, le=7 * 24 * 3600)

    # --- worker reliability (see services/worker/celery_app.py for why)
    task_soft_time_limit_s: int = Field(default=3300, gt=0)
    task_time_limit_s: int = Field(default=3600, gt=0)
    visibility_timeout_s: int = Field(default=4200, gt=0)
    unacked_restore_interval_s: int = Field(default=30, gt=0)
    max_attempts: int = Field(default=4, ge=1, le=20)
    retry_backoff_s: float = Field(default=5.0, ge=0)
    retry_backoff_max_s: float = Field(default=300.0, ge=0)
    progress_interval_s: float = Field(default=2.0, gt=0)
    heartbeat_interval_s: float = Field(
        default=20.0, gt=0, description="how often a running stage writes its heartbeat"
    )
    stall_limit_s: float = Field(
        default=180.0, gt=0, description="a running stage silent this long is re-queued"
    )
    sweep_interval_s: float = Field(
        default=30.0, gt=0, description="how often a worker looks for stalled stages"
    )
    work_dir: Path = Path(tempfile.gettempdir()) / "firefly3d-work"
    cache_max_bytes: int = Field(
        default=50 * GiB, ge=0, description="input cache per worker machine"
    )

    @model_validator(mode="after")
    def _check_time_limits(self) -> Self:
        if not self.task_soft_time_limit_s < self.task_time_limit_s < self.visibility_timeout_s:
            raise ValueError(
                "need task_soft_time_limit_s < task_time_limit_s < visibility_timeout_s "
                f"(got {self.task_soft_time_limit_s}, {self.task_time_limit_s}, "
                f"{self.visibility_timeout_s}): a task still running when the broker's "
                "visibility timeout expires would be delivered twice"
            )
        return self

    @model_validator(mode="after")
    def _check_heartbeat(self) -> Self:
        if not 2 * self.heartbeat_interval_s < self.stall_limit_s:
            raise ValueError(
                f"need 2 × heartbeat_interval_s < stall_limit_s (got {self.heartbeat_interval_s}, "
                f"{self.stall_limit_s}): a healthy stage must never look stalled"
            )
        return self

    @model_validator(mode="after")
    def _check_s3(self) -> Self:
        if self.storage_backend == "s3" and not self.s3_bucket:
            raise ValueError("FIREFLY3D_S3_BUCKET is required with FIREFLY3D_STORAGE_BACKEND=s3")
        return self

    def signing_key(self) -> str:
        """The key of signed links; the API refuses to start without it (see `create_app`)."""
        if self.secret_key is None:
            raise ValueError(
                "FIREFLY3D_SECRET_KEY is not set: it signs download links and must be the "
                "same in every API process (e.g. python -c 'import secrets; "
                "print(secrets.token_urlsafe(32))')"
            )
        return self.secret_key.get_secret_value()

    @property
    def cache_dir(self) -> Path:
        """Where a worker keeps downloaded input videos (same filesystem as its work dirs)."""
        return self.work_dir / "cache"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """Settings from the environment, read once per process."""
    return Settings()
