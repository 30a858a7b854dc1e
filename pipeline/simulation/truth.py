"""Ground truth of a simulated recording and its files (``truth.json``,
``truth_flashes.csv``, ``truth_artifacts.csv``)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from pipeline.geometry import Pose
from pipeline.simulation.tables import ArtifactTruth, FlashTruth

TRUTH_JSON = "truth.json"
FLASHES_CSV = "truth_flashes.csv"
ARTIFACTS_CSV = "truth_artifacts.csv"


@dataclass(frozen=True)
class GroundTruth:
    """What a simulated recording really contains.

    Attributes
    ----------
    delay_frames : int
        Camera-1 frame ``k`` shows the same instant as camera-2 frame ``k + delay``.
    pose : Pose
        ``R`` and unit ``t̂`` of camera 2 (DESIGN.md convention).
    separation_m, camera_height_m : float
        Baseline length and height of the cameras above the ground, metres.
    fps : float
    width, height : int
        Frame size in pixels.
    n_frames1, n_frames2 : int
        Frames recorded by each camera (over all its chapters).
    scenario : str
    seed : int
    flashes : FlashTruth
        One row per flash per frame.
    artifacts : ArtifactTruth
        Image positions of non-firefly lights and foliage per camera frame.
    extra : dict
        Everything else written to ``truth.json`` (the full configuration, camera
        gains, chapter files).
    """

    delay_frames: int
    pose: Pose
    separation_m: float
    camera_height_m: float
    fps: float
    width: int
    height: int
    n_frames1: int
    n_frames2: int
    scenario: str
    seed: int
    flashes: FlashTruth
    artifacts: ArtifactTruth
    extra: dict[str, Any] = field(default_factory=dict)

    _SCALARS: ClassVar[tuple[str, ...]] = (
        "delay_frames",
        "separation_m",
        "camera_height_m",
        "fps",
        "width",
        "height",
        "n_frames1",
        "n_frames2",
        "scenario",
        "seed",
    )

    def save(self, out_dir: str | Path) -> None:
        """Write ``truth.json`` (scalars, pose, extra) and the two CSV tables."""
        out = Path(out_dir)
        meta = {name: getattr(self, name) for name in self._SCALARS}
        meta.update(self.pose.to_dict(), **self.extra)
        (out / TRUTH_JSON).write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
        self.flashes.to_csv(out / FLASHES_CSV)
        self.artifacts.to_csv(out / ARTIFACTS_CSV)

    @classmethod
    def load(cls, out_dir: str | Path) -> GroundTruth:
        """Read the files written by `save`.

        Raises
        ------
        FileNotFoundError, ValueError
            Naming the missing or malformed file.
        """
        out = Path(out_dir)
        path = out / TRUTH_JSON
        try:
            meta = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise FileNotFoundError(f"{path}: no ground truth here") from None
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON: {exc}") from None
        missing = [k for k in (*cls._SCALARS, "rotation", "translation") if k not in meta]
        if missing:
            raise ValueError(f"{path}: missing key(s) {', '.join(missing)}")
        pose = Pose(
            rotation=np.array(meta.pop("rotation")), translation=np.array(meta.pop("translation"))
        )
        scalars = {name: meta.pop(name) for name in cls._SCALARS}
        return cls(
            **scalars,
            pose=pose,
            flashes=FlashTruth.from_csv(out / FLASHES_CSV),
            artifacts=ArtifactTruth.from_csv(out / ARTIFACTS_CSV),
            extra=meta,
        )
