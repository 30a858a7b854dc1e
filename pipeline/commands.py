"""Science sub-commands of ``firefly3d``: process, reconstruct, simulate, demo."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError
from tqdm import tqdm

from pipeline import artifacts

if TYPE_CHECKING:  # the stages load models and libraries: import them when a command runs
    from pipeline.night import NightInfo
    from pipeline.params import ProcessParams
    from pipeline.run import RunOutcome, RunProgress
    from pipeline.simulate import SimulatedRecording, SimulationConfig

#: Errors that mean "bad input": reported in one line, exit status 1, no traceback.
INPUT_ERRORS: tuple[type[Exception], ...] = (ValueError, FileNotFoundError, PermissionError)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``process``, ``reconstruct``, ``simulate`` and ``demo``."""
    _add_process(subparsers)
    _add_reconstruct(subparsers)
    _add_simulate(subparsers)
    _add_demo(subparsers)


# -- parameters shared by process / reconstruct / demo ------------------------------------


def _add_parameter_options(parser: argparse.ArgumentParser, *, tracking: bool) -> None:
    group = parser.add_argument_group("parameters")
    group.add_argument(
        "--params",
        type=Path,
        metavar="JSON",
        help="JSON file of parameter overrides, e.g. "
        '{"triangulation": {"gate": 0.3}} (see ProcessParams)',
    )
    if tracking:
        group.add_argument(
            "--threshold",
            type=float,
            help="tracking seed level in units of the noise sigma of the matched-filtered "
            "foreground (default 4; 4.85 when binned, at 4K and up)",
        )
        group.add_argument("--model", help="ONNX flash classifier (default: the shipped model)")
        group.add_argument("--model-card", help="model card JSON (default: beside the model)")
        group.add_argument(
            "--flash-threshold",
            type=float,
            help="accept candidates with flash probability >= this (default: the card's)",
        )
        group.add_argument(
            "--no-classifier",
            action="store_true",
            help="accept every candidate (no classifier, flicker test or acceptance "
            "evidence): the background-subtraction-only baseline",
        )
    group.add_argument(
        "--max-delay",
        type=float,
        metavar="SECONDS",
        help="largest |delay| between the cameras searched (default 120 s)",
    )


def _params_from_args(args: argparse.Namespace) -> ProcessParams:
    from pipeline.params import BACKGROUND_SUBTRACTION_ONLY, ProcessParams, with_overrides

    overrides: dict[str, Any] = {}
    if args.params:
        overrides = json.loads(Path(args.params).read_text(encoding="utf-8"))
    cli: dict[str, dict[str, Any]] = {
        "tracking": {"threshold": getattr(args, "threshold", None)},
        "classifier": {
            "model": getattr(args, "model", None),
            "card": getattr(args, "model_card", None),
            "threshold": getattr(args, "flash_threshold", None),
        },
        "sync": {"max_delay_s": args.max_delay},
    }
    if getattr(args, "no_classifier", False):
        overrides = with_overrides(overrides, BACKGROUND_SUBTRACTION_ONLY)
    for section, values in cli.items():
        chosen = {k: v for k, v in values.items() if v is not None}
        if chosen:
            overrides.setdefault(section, {}).update(chosen)
    return ProcessParams().merged(overrides)


def _add_night_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group(
        "the night",
        "Where and when the recording was made: placed in real time (timestamp_utc, "
        "minutes_after_sunset) and described in the data package (--package).",
    )
    group.add_argument("--site", help="where, in words")
    group.add_argument("--date", metavar="YYYY-MM-DD", help="local date the recording started")
    group.add_argument("--latitude", type=float, metavar="DEG", help="decimal degrees, north +")
    group.add_argument("--longitude", type=float, metavar="DEG", help="decimal degrees, east +")
    group.add_argument(
        "--time-zone",
        metavar="NAME",
        help="IANA time zone of the site, e.g. America/New_York (the cameras' clocks show "
        "local time: GoPro)",
    )
    group.add_argument(
        "--camera-clock",
        choices=("local", "utc"),
        default="local",
        help="how the videos' creation time is written: the camera's local wall-clock time "
        "(GoPro, default) or UTC",
    )
    group.add_argument(
        "--start-time",
        metavar="ISO",
        help="when camera 1's first frame was recorded, e.g. 2026-06-12T21:30:00-04:00 "
        "(without offset: local time in --time-zone); overrides the videos' creation time",
    )
    group.add_argument("--camera-model", metavar="TEXT", help="e.g. 'GoPro Max'")
    group.add_argument("--notes", default="", help="free text")
    group.add_argument(
        "--package",
        action="store_true",
        help="also write datapackage.json (Frictionless Data Package) and a zip of the "
        "results with it",
    )


def _night_from_args(args: argparse.Namespace) -> NightInfo:
    from pipeline.night import NightInfo

    return NightInfo(
        site=args.site,
        date=args.date,
        latitude=args.latitude,
        longitude=args.longitude,
        time_zone=args.time_zone,
        camera_clock=args.camera_clock,
        start_time=args.start_time,
        camera_model=args.camera_model,
        notes=args.notes,
    )


def _write_package(outcome: RunOutcome, night: NightInfo) -> None:
    from pipeline.package import write_package

    out = outcome.out_dir
    calibration_path = out / artifacts.CALIBRATION_JSON
    calibration = json.loads(calibration_path.read_text()) if calibration_path.exists() else None
    summary = json.loads((out / artifacts.SUMMARY_JSON).read_text())
    descriptor, archive = write_package(out, night, calibration, summary)
    print(f"data package       {descriptor.name} and {archive.name}")


class _RenamedOption(argparse.Action):
    """An option that was renamed: using it is an error that names the new spelling."""

    def __init__(self, option_strings: list[str], dest: str, new: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs="?", help=argparse.SUPPRESS, **kwargs)
        self.new = new

    def __call__(self, parser: argparse.ArgumentParser, *_: Any, **__: Any) -> None:
        parser.error(f"{self.option_strings[0]} was renamed {self.new}")


def _renamed(parser: argparse.ArgumentParser, old: str, new: str) -> None:
    parser.add_argument(old, action=_RenamedOption, new=new, dest=f"renamed_{old.strip('-')}")


# -- progress and summary -----------------------------------------------------------------


@contextmanager
def stage_bars(enabled: bool = True) -> Iterator[RunProgress]:
    """A progress bar per stage (on stderr), advanced by ``progress(label, fraction)``."""
    bars: dict[str, tqdm] = {}

    def progress(label: str, fraction: float) -> None:
        if not enabled:
            return
        bar = bars.get(label)
        if bar is None:
            for other in bars.values():
                other.close()
            bar = bars[label] = tqdm(
                total=1000,
                desc=f"{label:<12}",
                unit="‰",
                leave=True,
                file=sys.stderr,
                bar_format="{desc} {bar} {percentage:3.0f}% [{elapsed}<{remaining}]",
            )
        bar.update(max(0, round(fraction * 1000) - bar.n))

    try:
        yield progress
    finally:
        for bar in bars.values():
            bar.close()


def print_summary(outcome: RunOutcome) -> None:
    """A short account of a run: what was found and where the results are."""
    summary = json.loads((outcome.out_dir / artifacts.SUMMARY_JSON).read_text())
    lines = summary_lines(summary)
    lines.append(f"results in {outcome.out_dir.resolve()}")
    print("\n".join(lines))


def summary_lines(summary: dict[str, Any]) -> list[str]:
    """The lines of `print_summary` for a run's ``summary.json`` (without the folder)."""
    counts = summary["counts"]
    t = summary["translation"]
    lines = [
        "",
        *_recording_lines(summary),
        f"flashes accepted   cam1 {counts['flashes_cam1']}, cam2 {counts['flashes_cam2']}",
        f"delay              {summary['delay_frames']} frames "
        f"(confidence {summary['delay_confidence']:.2f})",
        f"calibration pairs  {counts['calibration_inliers']} inliers of "
        f"{counts['calibration_pairs']}; t = ({t[0]:+.3f}, {t[1]:+.3f}, {t[2]:+.3f})",
        f"3D flashes         {counts['points']} in {counts['streaks']} streaks, "
        f"{counts['trajectories']} trajectories",
        *_pattern_lines(summary),
        f"time               {sum(v or 0 for v in summary['timings_s'].values()):.1f} s",
    ]
    lines += [f"warning: {w}" for w in summary["warnings"]]
    return lines


def _recording_lines(summary: dict[str, Any]) -> list[str]:
    """Frame size, rate, codecs and the encoder's bits per pixel, as far as probed."""
    recording = summary.get("recording") or {}
    if not recording.get("width"):
        return []
    parts = [f"{recording['width']}×{recording['height']}", f"{recording['fps']:g} fps"]
    codecs = [recording.get(f"codec_cam{c}") for c in (1, 2)]
    if any(codecs):
        parts.append("/".join(dict.fromkeys(str(c) for c in codecs if c)))
    text = "recording          " + ", ".join(parts)
    bits = [recording.get(f"bits_per_pixel_cam{c}") for c in (1, 2)]
    if all(b is not None for b in bits):
        text += f"; {bits[0]:.3f} / {bits[1]:.3f} bit per pixel"
    return [text]


def _pattern_lines(summary: dict[str, Any]) -> list[str]:
    """The night's clock and flash pattern in a few lines (nothing that is unknown)."""
    lines = []
    clock = summary.get("clock") or {}
    if clock.get("start_utc"):
        after = clock.get("start_minutes_after_sunset")
        sunset = f", {after:+.0f} min after sunset" if after is not None else ""
        lines.append(f"recording started  {clock['start_utc']}{sunset}")
    night = summary.get("patterns") or {}
    duration, ifi = night.get("flash_duration_s") or {}, night.get("ifi_s") or {}
    if duration.get("median") is not None:
        text = f"flash duration     median {duration['median']:.3f} s"
        if ifi.get("median") is not None:
            text += f"; inter-flash interval median {ifi['median']:.3f} s"
        lines.append(text)
    if night.get("synchronous") is not None:
        verdict = "yes" if night["synchronous"] else "no"
        lines.append(
            f"synchrony          {verdict} (strength {night['strength']:.2f} at "
            f"{night['period_s']:.2f} s, z = {night['z']:.1f})"
            if night.get("period_s") is not None
            else f"synchrony          {verdict}"
        )
    return lines


def _run_with_params(
    args: argparse.Namespace,
    action: Callable[[ProcessParams, RunProgress, NightInfo], RunOutcome],
) -> int:
    """Run with the options' parameters, night and progress bars; print the summary.

    Invalid parameters or night options exit with status 2, bad input (files, values)
    with 1; either way one readable message on stderr and no traceback. With
    ``--package`` the data package is written after the run.
    """
    from pipeline.night import NightInfo

    try:
        params = _params_from_args(args)
        night = _night_from_args(args) if hasattr(args, "site") else NightInfo()
    except ValidationError as exc:
        print(f"error: invalid parameters:\n{exc}", file=sys.stderr)
        return 2
    try:
        with stage_bars(enabled=not args.quiet) as progress:
            outcome = action(params, progress, night)
        print_summary(outcome)
        if getattr(args, "package", False):
            _write_package(outcome, night)
    except INPUT_ERRORS as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


def _add_run_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--separation", type=float, required=True, metavar="METRES", help="camera separation"
    )
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="result folder")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


# -- process ------------------------------------------------------------------------------


def _add_process(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "process",
        help="two cameras' videos in, 3D flash trajectories out",
        description="Track, classify, calibrate, triangulate and link the flashes of a "
        "stereo 360-degree recording. Give each camera's chapter files in order.",
    )
    parser.add_argument("--cam1", type=Path, action="append", required=True, metavar="FILE")
    parser.add_argument("--cam2", type=Path, action="append", required=True, metavar="FILE")
    parser.add_argument(
        "--camera-height", type=float, metavar="METRES", help="camera height above the ground"
    )
    _renamed(parser, "--height", "--camera-height")
    _add_run_options(parser)
    _add_night_options(parser)
    _add_parameter_options(parser, tracking=True)
    parser.set_defaults(func=_process)


def _process(args: argparse.Namespace) -> int:
    from pipeline.run import process

    return _run_with_params(
        args,
        lambda params, progress, night: process(
            args.cam1,
            args.cam2,
            args.separation,
            args.out,
            params,
            progress,
            camera_height_m=args.camera_height,
            night=night,
        ),
    )


# -- reconstruct ---------------------------------------------------------------------------


def _add_reconstruct(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "reconstruct",
        help="per-camera detections in, 3D flash trajectories out",
        description="Calibrate, triangulate and link from per-camera detections "
        "(CSV files whose header has at least frame,x,y; x = column, y = row, pixels).",
    )
    parser.add_argument("--flashes1", type=Path, required=True, metavar="CSV")
    parser.add_argument("--flashes2", type=Path, required=True, metavar="CSV")
    parser.add_argument("--frame-width", type=int, required=True, help="frame width, pixels")
    parser.add_argument("--frame-height", type=int, required=True, help="frame height, pixels")
    _renamed(parser, "--width", "--frame-width")
    _renamed(parser, "--height", "--frame-height")
    parser.add_argument("--fps", type=float, required=True)
    parser.add_argument(
        "--camera-height", type=float, metavar="METRES", help="camera height above the ground"
    )
    _add_run_options(parser)
    _add_night_options(parser)
    _add_parameter_options(parser, tracking=False)
    parser.set_defaults(func=_reconstruct)


def _reconstruct(args: argparse.Namespace) -> int:
    from pipeline.run import reconstruct

    return _run_with_params(
        args,
        lambda params, progress, night: reconstruct(
            args.flashes1,
            args.flashes2,
            args.frame_width,
            args.frame_height,
            args.fps,
            args.separation,
            args.out,
            params,
            progress,
            night=night,
            camera_height_m=args.camera_height,
        ),
    )


# -- simulate ------------------------------------------------------------------------------


def _add_simulate(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "simulate",
        help="render a synthetic stereo recording with ground truth",
        description="Render two cameras' equirectangular videos of fireflies (and "
        "artifacts) with known delay, pose and 3D flashes.",
    )
    parser.add_argument("--out", type=Path, required=True, metavar="DIR")
    parser.add_argument(
        "--scenario",
        default="clean",
        help="clean, twilight, lights, headlights, foliage, field, real3d, or the harder "
        "hard-clean, hard-wind, hard-all, hard-swarm, hard-species, hard-noisy "
        "(see pipeline.simulation.config.SCENARIOS)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--width", type=int, default=640, help="frame width (height = width/2)")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--separation", type=float, default=1.5, metavar="METRES")
    parser.add_argument("--delay", type=int, metavar="FRAMES", help="default: drawn from the seed")
    parser.add_argument("--codec", choices=("h264", "hevc"), default="h264")
    parser.add_argument(
        "--chapters",
        type=int,
        nargs=2,
        default=(1, 1),
        metavar=("CAM1", "CAM2"),
        help="number of chapter files per camera",
    )
    parser.add_argument("--real3d", type=Path, metavar="CSV", help="x,y,z,frame flights to replay")
    parser.set_defaults(func=_simulate)


def _render(config: SimulationConfig, out: Path, quiet: bool) -> SimulatedRecording:
    """Simulate a recording with a progress bar over both cameras' frames."""
    from pipeline.simulate import simulate

    total = 2 * round(config.seconds * config.fps)
    with tqdm(total=total, desc="simulate", unit="frame", file=sys.stderr, disable=quiet) as bar:
        return simulate(config, out, progress=bar.update)


def _simulate(args: argparse.Namespace) -> int:
    from pipeline.simulate import SimulationConfig

    try:
        config = SimulationConfig(
            scenario=args.scenario,
            seed=args.seed,
            width=args.width,
            seconds=args.seconds,
            fps=args.fps,
            separation_m=args.separation,
            delay_frames=args.delay,
            codec=args.codec,
            chapters=tuple(args.chapters),
            real3d_csv=args.real3d,
        )
    except ValidationError as exc:
        print(f"error: invalid simulation settings:\n{exc}", file=sys.stderr)
        return 2
    recording = _render(config, args.out, quiet=False)
    truth = recording.truth
    print(
        f"cam1: {' '.join(str(p) for p in recording.cam1)}\n"
        f"cam2: {' '.join(str(p) for p in recording.cam2)}\n"
        f"delay {truth.delay_frames} frames, separation {truth.separation_m} m; "
        f"ground truth in {Path(args.out).resolve()}"
    )
    return 0


# -- demo ------------------------------------------------------------------------------------


def _add_demo(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="simulate a small recording, process it and print the accuracy",
        description="Render a 640x320 stereo recording with known delay, pose and flashes, "
        "run the whole pipeline on it and compare the results with the ground truth.",
    )
    parser.add_argument("--out", type=Path, help="folder for the recording and results")
    parser.add_argument("--scenario", default="field", help="simulator scenario")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    _add_parameter_options(parser, tracking=True)
    parser.set_defaults(func=_demo)


def _demo(args: argparse.Namespace) -> int:
    from pipeline.evaluate import evaluate_run, format_accuracy
    from pipeline.run import process
    from pipeline.simulate import SimulationConfig

    out = args.out or Path(tempfile.mkdtemp(prefix="firefly3d-demo-"))
    config = SimulationConfig(scenario=args.scenario, seed=args.seed, seconds=args.seconds)
    recording = _render(config, out / "recording", args.quiet)
    code = _run_with_params(
        args,
        lambda params, progress, night: process(
            recording.cam1,
            recording.cam2,
            config.separation_m,
            out / "results",
            params,
            progress,
            camera_height_m=config.camera_height_m,
            night=night,
        ),
    )
    if code:
        return code
    print("\naccuracy against the simulator's ground truth")
    print(format_accuracy(evaluate_run(out / "results", recording.truth)))
    print(f"\nrecording in {(out / 'recording').resolve()}")
    print(f"results in {(out / 'results').resolve()}")
    return 0
