"""Bad input to `firefly3d process` / `reconstruct`: a clear message, nothing lost."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline import artifacts
from pipeline.cli import main
from tests.pipeline.video_factory import overwrite_sample, truncate, write_video

pytestmark = pytest.mark.slow


def process(cam1: list[Path], cam2: list[Path], out: Path, separation: float = 1.5) -> int:
    args = ["process", "--quiet", "--separation", str(separation), "--out", str(out)]
    args += [a for p in cam1 for a in ("--cam1", str(p))]
    args += [a for p in cam2 for a in ("--cam2", str(p))]
    return main(args)


def noise_pictures(n: int, width: int = 640, height: int = 320, seed: int = 0):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        yield rng.integers(5, 20, size=(height, width), dtype=np.uint8)


def test_non_equirectangular(tmp_path, capsys) -> None:
    video = write_video(tmp_path / "wide.mp4", noise_pictures(10, 640, 360))
    assert process([video], [video], tmp_path / "out") == 1
    err = capsys.readouterr().err
    assert "wide.mp4" in err and "equirectangular" in err and "640" in err


def test_different_fps(tmp_path, capsys) -> None:
    a = write_video(tmp_path / "a.mp4", noise_pictures(10), fps=30)
    b = write_video(tmp_path / "b.mp4", noise_pictures(10), fps=25)
    assert process([a], [b], tmp_path / "out") == 1
    err = capsys.readouterr().err
    assert "fps" in err and "30" in err and "25" in err


def test_truncated_upload(simulated, tmp_path, capsys) -> None:
    recording = simulated(scenario="clean", seed=3)
    cut = tmp_path / "cam1_cut.mp4"
    shutil.copy(recording.cam1[0], cut)
    truncate(cut, 0.6)
    assert process([cut], recording.cam2, tmp_path / "out") == 1
    assert "cam1_cut.mp4" in capsys.readouterr().err


def test_corrupt_frame_names_file_and_frame_and_keeps_the_probe(
    simulated, tmp_path, capsys
) -> None:
    recording = simulated(scenario="clean", seed=3)
    bad = tmp_path / "cam2_bad.mp4"
    shutil.copy(recording.cam2[0], bad)
    overwrite_sample(bad, 200)
    out = tmp_path / "out"
    assert process(recording.cam1, [bad], out) == 1
    err = capsys.readouterr().err
    assert "cam2_bad.mp4" in err and "frame" in err
    assert (out / artifacts.PROBE_JSON).exists()  # what was computed survives


def test_no_flashes(tmp_path, capsys) -> None:
    a = write_video(tmp_path / "a.mp4", noise_pictures(90, seed=1))
    b = write_video(tmp_path / "b.mp4", noise_pictures(90, seed=2))
    assert process([a], [b], tmp_path / "out") == 1
    assert "no flash" in capsys.readouterr().err.lower()


@pytest.mark.parametrize("separation", ["-1", "0", "1e6", "nan"])
def test_absurd_separation(tmp_path, capsys, separation: str) -> None:
    video = write_video(tmp_path / "v.mp4", noise_pictures(5))
    assert process([video], [video], tmp_path / "out", separation=float(separation)) == 1
    assert "separation" in capsys.readouterr().err


def test_missing_file(tmp_path, capsys) -> None:
    assert process([tmp_path / "nope.mp4"], [tmp_path / "nope2.mp4"], tmp_path / "out") == 1
    assert "nope.mp4" in capsys.readouterr().err


def test_reconstruct_bad_csv(tmp_path, capsys) -> None:
    good = tmp_path / "good.csv"
    good.write_text("frame,x,y\n1,10,20\n")
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,u,v\n1,10,20\n")
    code = main(
        [
            "reconstruct",
            "--quiet",
            "--flashes1",
            str(good),
            "--flashes2",
            str(bad),
            "--frame-width",
            "640",
            "--frame-height",
            "320",
            "--fps",
            "30",
            "--separation",
            "1.5",
            "--out",
            str(tmp_path / "out"),
        ]
    )
    assert code == 1
    err = capsys.readouterr().err
    assert "bad.csv" in err and "missing column" in err


def test_invalid_parameter_override(tmp_path, capsys) -> None:
    params = tmp_path / "params.json"
    params.write_text('{"triangulation": {"gate": -1}}')
    video = write_video(tmp_path / "v.mp4", noise_pictures(5))
    code = main(
        [
            "process",
            "--quiet",
            "--cam1",
            str(video),
            "--cam2",
            str(video),
            "--separation",
            "1.5",
            "--out",
            str(tmp_path / "out"),
            "--params",
            str(params),
        ]
    )
    assert code == 2
    assert "gate" in capsys.readouterr().err
