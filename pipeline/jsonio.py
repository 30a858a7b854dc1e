"""JSON files and values: numpy scalars and arrays, paths and non-finite floats handled once."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any


def _default(value: Any) -> Any:
    # numpy scalars and arrays without importing numpy: both have `tolist`.
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot serialise {type(value).__name__} to JSON")


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write `data` as indented JSON (parent folders created; NaN kept as ``NaN``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, default=_default) + "\n", encoding="utf-8")


def read_json(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text(encoding="utf-8"))


def json_safe(value: Any) -> Any:
    """`value` as strict JSON data: numpy values as plain numbers and lists, keys as
    strings, NaN and infinities as None (PostgreSQL's JSONB refuses them)."""

    def finite(obj: Any) -> Any:
        if isinstance(obj, float):
            return obj if math.isfinite(obj) else None
        if isinstance(obj, dict):
            return {str(k): finite(v) for k, v in obj.items()}
        if isinstance(obj, list):
            return [finite(v) for v in obj]
        return obj

    return finite(json.loads(json.dumps(value, default=_default, allow_nan=True)))
