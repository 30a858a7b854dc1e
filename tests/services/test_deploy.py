"""Deployment files: docker-compose.yml is valid, .env.example documents every setting."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

from services.core.settings import Settings

ROOT = Path(__file__).resolve().parents[2]


def test_compose_file_is_valid() -> None:
    compose = shutil.which("docker-compose")
    assert compose, "docker-compose is needed: apt-get install -y docker-compose"
    result = subprocess.run(
        [compose, "-f", str(ROOT / "docker-compose.yml"), "config", "-q"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    services = subprocess.run(
        [compose, "-f", str(ROOT / "docker-compose.yml"), "config", "--services"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert {"postgres", "redis", "minio", "minio-setup", "api", "worker"} <= set(services)


def test_env_example_documents_every_setting() -> None:
    text = (ROOT / ".env.example").read_text()
    documented = re.findall(r"^FIREFLY3D_([A-Z0-9_]+)=", text, flags=re.MULTILINE)
    assert sorted(documented) == sorted(name.upper() for name in Settings.model_fields)
    # and the defaults written there are the real ones
    values = dict(re.findall(r"^FIREFLY3D_([A-Z0-9_]+)=(.*)$", text, flags=re.MULTILINE))
    defaults = Settings(secret_key="x")
    for name, value in values.items():
        default = getattr(defaults, name.lower())
        # WORK_DIR follows TMPDIR; secrets have no default to show
        if value and name != "WORK_DIR" and not hasattr(default, "get_secret_value"):
            assert str(default) == value, name
