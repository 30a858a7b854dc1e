"""The processing parameters as a flat list (dotted name, description, type, default).

The admin page offers them for re-run overrides with their descriptions, and error
messages name them by the same dotted names (``sync.window_s``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

from pipeline.params import ProcessParams


@dataclass(frozen=True)
class Parameter:
    path: str
    description: str
    type: str
    default: Any


def parameters(model: type[BaseModel] = ProcessParams, prefix: str = "") -> list[Parameter]:
    """Every leaf parameter of `model`, in declaration order."""
    found = []
    defaults = model().model_dump(mode="json")
    for name, field in model.model_fields.items():
        path = f"{prefix}{name}"
        kind = field.annotation
        if isinstance(kind, type) and issubclass(kind, BaseModel):
            found += parameters(kind, f"{path}.")
        else:
            label = kind.__name__ if isinstance(kind, type) else str(kind).replace("typing.", "")
            found.append(Parameter(path, field.description or "", label, defaults[name]))
    return found
