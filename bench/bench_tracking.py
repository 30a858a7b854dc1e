"""Tracking throughput against decoding alone, and memory against recording length.

Prints, for one recording (``--video``, or a generated 3840×1920 H.264 one of a few
seconds with small moving blobs over a noisy dark background, cached in the temp dir):

* decode-only fps: `pipeline.video.iter_frames` (decode + luminance plane);
* tracking fps: `pipeline.tracking.track` (decode + background + blobs + patches +
  classification with the shipped model, or ``--model``), and its ratio to decoding;
* an OpenCV baseline on the same decoded luminance (MOG2 background subtractor +
  connectedComponentsWithStats) and its ratio to decoding;
* peak RSS of tracking the recording once and three times over (as three chapters), in
  fresh processes, to show memory does not grow with the length.

The three runs alternate for ``--repeat`` rounds and ratios are taken within a round
(the machine is shared); CPU time per frame (all threads) is printed too, as
``decode CPU / tracking CPU``: the throughput ratio when every core is busy, and much
less sensitive to other processes than wall-clock rates.
``--profile`` prints the top functions of one tracking run (cProfile).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import av
import cv2
import numpy as np

from pipeline.params import TrackingParams
from pipeline.probe import VideoInfo
from pipeline.tracking import PatchClassifier, track
from pipeline.video import iter_frames, probe_video


def make_recording(width: int, seconds: float, fps: int = 30) -> Path:
    """A cached H.264 recording: dark sensor noise, a few lamps and moving blinking blobs."""
    height = width // 2
    path = Path(tempfile.gettempdir()) / "firefly3d-bench" / f"blobs_{width}_{seconds:g}s.mp4"
    if path.exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    noise = [rng.normal(14, 3, (height, width)).clip(0, 255).astype(np.uint8) for _ in range(6)]
    n_blobs = 60
    start = rng.uniform([0, height * 0.2], [width, height * 0.8], (n_blobs, 2))
    velocity = rng.normal(0, 3, (n_blobs, 2))
    chroma = np.full((height // 2, width), 128, np.uint8)
    partial = path.with_suffix(".part.mp4")
    with av.open(str(partial), "w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"preset": "veryfast", "crf": "20"}
        for k in range(round(seconds * fps)):
            luma = noise[k % len(noise)].copy()
            luma[height // 3 : height // 3 + 4, 100:104] = 240  # a lamp
            centres = (start + k * velocity) % [width, height]
            lit = (k + np.arange(n_blobs)) % 7 < 3  # blinking
            for u, v in centres[lit].astype(int):
                luma[max(v - 2, 0) : v + 2, max(u - 2, 0) : u + 2] = 220
            frame = av.VideoFrame.from_ndarray(np.vstack([luma, chroma]), format="yuv420p")
            container.mux(stream.encode(frame))
        container.mux(stream.encode(None))
    partial.rename(path)
    return path


def load_classifier(model: str | None) -> tuple[PatchClassifier | None, str]:
    try:
        from pipeline.classify import FlashClassifier
    except ImportError:
        return None, "none (pipeline.classify is not available): tracking without classifier"
    try:
        classifier = FlashClassifier.load(model)
    except (OSError, ValueError) as exc:
        return None, f"none ({exc}): tracking without classifier"
    return classifier, f"{model or 'shipped default model'} ({classifier.input_size} px patches)"


@dataclass(frozen=True)
class Timing:
    fps: float  # wall clock
    cpu_ms: float  # CPU time of all the process's threads, per frame


def timed(run: Callable[[], int]) -> Timing:
    """Throughput of `run`, which returns the number of frames it processed."""
    wall, cpu = time.perf_counter(), time.process_time()
    frames = run()
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return Timing(frames / wall, 1e3 * cpu / frames)


def _join(values: list[float]) -> str:
    return ", ".join(f"{v:.2f}" for v in values)


def decode_only(info: VideoInfo) -> int:
    checksum = 0
    for frame in iter_frames(info):
        checksum += int(frame.y[0, 0])  # touch the luminance plane
    return info.n_frames


def opencv_baseline(info: VideoInfo) -> int:
    subtractor = cv2.createBackgroundSubtractorMOG2(history=round(2 * info.fps))
    for frame in iter_frames(info):
        mask = subtractor.apply(frame.y)
        cv2.connectedComponentsWithStats(mask, connectivity=8)
    return info.n_frames


def peak_rss_mb(paths: list[str], copies: int, model: str | None, classify: bool) -> float:
    """Peak RSS of a fresh process tracking the recording `copies` times over."""
    command = [sys.executable, __file__, "--rss-child", str(copies), "--video", *paths]
    if model:
        command += ["--model", model]
    if not classify:
        command.append("--no-classifier")
    out = subprocess.run(command, check=True, capture_output=True, text=True).stdout
    return float(json.loads(out.strip().splitlines()[-1])["peak_rss_mb"])


def rss_child(paths: list[str], copies: int, classifier: PatchClassifier | None) -> None:
    info = probe_video(paths * copies)
    track(info, classifier=classifier)
    print(json.dumps({"frames": info.n_frames, "peak_rss_mb": _peak_rss_kb() / 1024}))


def _peak_rss_kb() -> int:
    """This process's peak RSS. ``ru_maxrss`` keeps the parent's peak across fork and
    exec, so Linux's per-address-space high-water mark is read when available."""
    status = Path("/proc/self/status")
    if status.exists():
        for line in status.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--video", nargs="+", help="chapter files of one recording")
    parser.add_argument("--width", type=int, default=3840, help="generated recording width")
    parser.add_argument("--seconds", type=float, default=4.0, help="generated length, s")
    parser.add_argument("--model", help="ONNX classifier (default: the shipped one)")
    parser.add_argument("--no-classifier", action="store_true", help="track without it")
    parser.add_argument("--repeat", type=int, default=3, help="rounds of the three runs")
    parser.add_argument(
        "--params",
        type=json.loads,
        default={},
        metavar="JSON",
        help="TrackingParams overrides, e.g. '{\"deblend\": false}'",
    )
    parser.add_argument("--profile", action="store_true", help="cProfile one tracking run")
    parser.add_argument("--rss-child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    paths = args.video or [str(make_recording(args.width, args.seconds))]
    classifier, classifier_note = (
        (None, "disabled (--no-classifier)") if args.no_classifier else load_classifier(args.model)
    )
    if args.rss_child:
        rss_child(paths, args.rss_child, classifier)
        return 0

    info = probe_video(paths)
    params = TrackingParams.model_validate(args.params)
    print(f"recording: {', '.join(paths)}")
    print(f"  {info.width}×{info.height} {info.codec} {info.fps:.2f} fps, {info.n_frames} frames")
    print(f"classifier: {classifier_note}")
    print(f"cv2 threads: {cv2.getNumThreads()}")
    print(f"tracking overrides: {args.params or 'none'}")

    candidates = 0

    def tracking() -> int:
        nonlocal candidates
        candidates = len(track(info, params=params, classifier=classifier))
        return info.n_frames

    # Runs alternate, and ratios are taken within each round: the machine is shared.
    runs: dict[str, list[Timing]] = {"decode": [], "track": [], "opencv": []}
    for _ in range(args.repeat):
        runs["decode"].append(timed(lambda: decode_only(info)))
        runs["track"].append(timed(tracking))
        runs["opencv"].append(timed(lambda: opencv_baseline(info)))
    print("                    wall fps (best)  fps ratio to decode   CPU ms/frame (ratio)")
    for name, label in (
        ("decode", "decode only"),
        ("track", "tracking"),
        ("opencv", "OpenCV MOG2 + CC"),
    ):
        ratios = [t.fps / d.fps for t, d in zip(runs[name], runs["decode"], strict=True)]
        cpu = statistics.median(t.cpu_ms for t in runs[name])
        cpu_decode = statistics.median(t.cpu_ms for t in runs["decode"])
        print(
            f"{label:18s} {max(t.fps for t in runs[name]):8.1f}      "
            f"median {statistics.median(ratios):.2f} (runs {_join(ratios)})   "
            f"{cpu:6.1f} ({cpu_decode / cpu:.2f} × decode throughput)"
        )
    print(f"candidates per frame: {candidates / info.n_frames:.1f}")

    rss = {n: peak_rss_mb(paths, n, args.model, classifier is not None) for n in (1, 3)}
    print(
        f"peak RSS: {rss[1]:.0f} MB for {info.n_frames} frames, "
        f"{rss[3]:.0f} MB for {3 * info.n_frames} frames (×{rss[3] / rss[1]:.2f})"
    )

    if args.profile:
        profiler = cProfile.Profile()
        profiler.runcall(tracking)
        pstats.Stats(profiler).sort_stats("tottime").print_stats(15)
    return 0


if __name__ == "__main__":
    sys.exit(main())
