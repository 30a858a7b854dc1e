"""Fixtures shared by every test package."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from pipeline.simulate import SimulatedRecording, SimulationConfig, simulate

SimulateFactory = Callable[..., SimulatedRecording]


@pytest.fixture(scope="session")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> SimulateFactory:
    """Render (once per session) the simulated recording of a configuration.

    ``simulated(scenario="field", seed=1, seconds=20)`` takes `SimulationConfig`
    fields; recordings are small (640×320 by default) and cached by configuration.
    """
    cache: dict[str, SimulatedRecording] = {}
    root = tmp_path_factory.mktemp("recordings")

    def make(**fields: Any) -> SimulatedRecording:
        config = SimulationConfig(**fields)
        key = config.model_dump_json()
        if key not in cache:
            cache[key] = simulate(config, root / f"rec{len(cache):02d}")
        return cache[key]

    return make


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The project's ../shared folder (data for tests and evaluation; not shipped)."""
    return Path(__file__).resolve().parents[2] / "shared"
