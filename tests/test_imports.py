"""What a process loads: the API and the CLI's start-up stay free of the science libraries."""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY = ("onnxruntime", "av", "cv2", "scipy", "torch", "matplotlib")


def loaded_after(code: str) -> list[str]:
    """The `HEAVY` modules a fresh interpreter holds after running `code`."""
    probe = (
        f"{code}\nimport json, sys\nprint(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    return list(json.loads(result.stdout.splitlines()[-1]))


def test_the_api_loads_no_science_library() -> None:
    assert loaded_after("from services.api.app import create_app") == []


def test_the_cli_builds_its_parser_without_science_libraries() -> None:
    assert loaded_after("from pipeline.cli import build_parser; build_parser()") == []


def test_validating_parameters_and_planning_loads_no_science_library() -> None:
    code = (
        "from pipeline.graph import plan\n"
        "from pipeline.params import ProcessParams\n"
        "from pipeline.probe import StereoProbe\n"
        "plan(StereoProbe(640, 320, 30.0, {1: 900, 2: 900}), ProcessParams())"
    )
    assert loaded_after(code) == []
