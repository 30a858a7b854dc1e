"""Settings come from FIREFLY3D_* variables and refuse unsafe reliability limits."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from services.core.settings import Settings


def test_environment_variables_are_read(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FIREFLY3D_STORAGE_BACKEND", "s3")
    monkeypatch.setenv("FIREFLY3D_S3_BUCKET", "night-videos")
    monkeypatch.setenv("FIREFLY3D_MAX_ATTEMPTS", "7")
    monkeypatch.setenv("FIREFLY3D_ADMIN_TOKEN", "sesame")
    settings = Settings()
    assert (settings.storage_backend, settings.s3_bucket, settings.max_attempts) == (
        "s3",
        "night-videos",
        7,
    )
    assert settings.admin_token is not None and settings.admin_token.get_secret_value() == "sesame"
    assert "sesame" not in repr(settings)


def test_visibility_timeout_must_exceed_the_hard_time_limit() -> None:
    with pytest.raises(ValidationError, match="would be delivered twice"):
        Settings(task_soft_time_limit_s=50, task_time_limit_s=60, visibility_timeout_s=60)
    with pytest.raises(ValidationError, match="task_soft_time_limit_s < task_time_limit_s"):
        Settings(task_soft_time_limit_s=70, task_time_limit_s=60, visibility_timeout_s=100)


def test_bad_backend_is_refused() -> None:
    with pytest.raises(ValidationError, match="storage_backend"):
        Settings(storage_backend="ftp")  # type: ignore[arg-type]
