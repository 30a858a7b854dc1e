"""The probe stage on real encoded files: what it measures and what it warns about."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.graph import StageContext, Unit
from pipeline.params import ProcessParams
from pipeline.probe import LOW_BITS_PER_PIXEL
from pipeline.stages import probe
from tests.pipeline import video_factory as vf


def _grainy_pictures(n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [
        np.clip(30 + rng.normal(0, 6, (320, 640, 1)), 0, 255).astype(np.uint8).repeat(3, axis=2)
        for _ in range(n)
    ]


def _probe_pair(tmp_path: Path, crf: int) -> tuple[dict[str, object], list[str]]:
    videos = {
        camera: {
            0: vf.write_video(tmp_path / f"cam{camera}.mp4", _grainy_pictures(8, camera), crf=crf)
        }
        for camera in (1, 2)
    }
    context = StageContext(
        workdir=tmp_path,
        unit=Unit("probe"),
        params=ProcessParams(),
        separation_m=1.5,
        videos=videos,
    )
    result = probe(context)
    return result.metrics, result.warnings


def test_a_starved_encoding_is_reported_per_camera(tmp_path: Path) -> None:
    metrics, warnings = _probe_pair(tmp_path, crf=51)
    for camera in (1, 2):
        bpp = metrics[f"bits_per_pixel_cam{camera}"]
        assert isinstance(bpp, float) and 0 < bpp < LOW_BITS_PER_PIXEL
    assert [w.split(":")[0] for w in warnings] == ["camera 1", "camera 2"]
    assert all("compression erases faint flashes" in w for w in warnings)


def test_grain_kept_by_the_encoder_is_not_warned_about(tmp_path: Path) -> None:
    metrics, warnings = _probe_pair(tmp_path, crf=0)
    assert metrics["bits_per_pixel_cam1"] > 1.0  # lossless grain costs bits
    assert warnings == []
