"""The account of a run that `firefly3d process` prints."""

from __future__ import annotations

from typing import Any

from pipeline.commands import summary_lines
from pipeline.params import ProcessParams
from pipeline.summary import summarise


def _summary(recording: dict[str, Any] | None) -> dict[str, Any]:
    summary = summarise({}, ProcessParams())
    summary["translation"] = [0.0, 1.0, 0.0]
    summary["delay_confidence"] = 0.9
    summary["recording"] = recording
    summary["warnings"] = ["camera 2: encoded at 0.050 bit per pixel and frame"]
    return summary


def test_the_recording_line_gives_size_rate_codec_and_bits_per_pixel() -> None:
    recording = {"width": 640, "height": 320, "fps": 29.97002997, "codec_cam1": "h264"}
    recording |= {"codec_cam2": "h264", "bits_per_pixel_cam1": 0.16, "bits_per_pixel_cam2": 0.05}
    lines = summary_lines(_summary(recording))
    assert "recording          640×320, 29.97 fps, h264; 0.160 / 0.050 bit per pixel" in lines
    assert lines[-1] == "warning: camera 2: encoded at 0.050 bit per pixel and frame"


def test_a_run_from_detections_gives_size_and_rate_only() -> None:
    lines = summary_lines(_summary({"width": 5760, "height": 2880, "fps": 30.0}))
    assert "recording          5760×2880, 30 fps" in lines
    assert not any(line.startswith("recording") for line in summary_lines(_summary(None)))
