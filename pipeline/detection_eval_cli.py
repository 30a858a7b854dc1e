"""``firefly3d eval-detection``: detection recall and precision against ground truth.

For each (scenario, seed) it simulates a recording (cached by configuration), runs the
whole pipeline on it (`pipeline.run.process`) and scores the result folder
(`pipeline.detection_eval`); or it scores existing recordings (``--recording``) and
existing result folders (``--results``). Prints a table and, with ``--json``, writes
every figure.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import sys
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from pipeline import artifacts

if TYPE_CHECKING:
    from pipeline.params import ProcessParams
    from pipeline.simulate import GroundTruth, SimulationConfig


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``eval-detection``."""
    parser = subparsers.add_parser(
        "eval-detection",
        help="2D/3D detection recall and precision against simulated ground truth",
        description="Simulate recordings (or take existing ones with ground truth), run the "
        "pipeline and print, per scenario and seed, 2D recall and precision per camera "
        "(binned by peak SNR and range), candidates per frame, and 3D recall and precision.",
    )
    source = parser.add_argument_group("what to score")
    source.add_argument(
        "--scenario",
        action="append",
        metavar="NAME",
        help="simulator scenario (repeatable), e.g. clean, hard-clean, hard-wind, hard-all",
    )
    source.add_argument("--seeds", type=int, nargs="+", default=[1], metavar="SEED")
    source.add_argument("--seconds", type=float, default=20.0)
    source.add_argument("--width", type=int, default=640, help="frame width (height = width/2)")
    source.add_argument(
        "--sim-params",
        type=Path,
        metavar="JSON",
        help="JSON file of SimulationConfig fields applied to every simulated scenario",
    )
    source.add_argument(
        "--lossless-twin",
        action="store_true",
        help="also score every simulated night encoded losslessly (same scene, fireflies "
        "and sensor noise; H.264 with the luma bit-exact): what the encoder loses, apart "
        "from what detection loses",
    )
    source.add_argument(
        "--recording",
        type=Path,
        action="append",
        metavar="DIR",
        help="an existing simulated recording with its truth files (repeatable)",
    )
    source.add_argument(
        "--results",
        type=Path,
        action="append",
        metavar="DIR",
        help="score this existing result folder instead of running the pipeline (one per "
        "--recording, in order)",
    )
    run = parser.add_argument_group("pipeline")
    run.add_argument(
        "--params",
        type=Path,
        metavar="JSON",
        help='JSON file of ProcessParams overrides, e.g. {"tracking": {"threshold": 0.05}}',
    )
    run.add_argument(
        "--no-classifier",
        action="store_true",
        help="no classifier, no flicker test: the background-subtraction-only baseline",
    )
    run.add_argument(
        "--cache",
        type=Path,
        default=_default_cache(),
        metavar="DIR",
        help="where simulated recordings are kept and reused (default: %(default)s)",
    )
    run.add_argument(
        "--out",
        type=Path,
        metavar="DIR",
        help="result folders go to DIR/<night> (default: next to each recording)",
    )
    run.add_argument(
        "--reuse-results",
        action="store_true",
        help="score an existing result folder of the same parameters instead of re-running",
    )
    output = parser.add_argument_group("output")
    output.add_argument("--json", type=Path, metavar="FILE", help="write every figure as JSON")
    output.add_argument("--bins", action="store_true", help="also print recall per bin")
    output.add_argument(
        "--cuts",
        type=_probability,
        nargs="+",
        default=(),
        metavar="P",
        help="also score each run as if the evidence model had accepted the candidates of "
        "flash probability >= P (from the run's own probabilities, without running it "
        "again): what acceptance.evidence_threshold trades between recall and precision",
    )
    output.add_argument("--quiet", action="store_true", help="no progress messages")
    parser.set_defaults(func=_eval_detection)


def _probability(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text} is not a probability in [0, 1]")
    return value


def _default_cache() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "firefly3d" / "eval-detection"


def _digest(payload: Any) -> str:
    text = json.dumps(payload, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:10]


def _log(args: argparse.Namespace, message: str) -> None:
    if not args.quiet:
        print(message, file=sys.stderr, flush=True)


# -- parameters ------------------------------------------------------------------------


def process_params(overrides_file: Path | None, no_classifier: bool) -> ProcessParams:
    """`ProcessParams` with a JSON file's overrides; ``no_classifier`` gives the
    background-subtraction-only baseline (as ``firefly3d process --no-classifier``)."""
    from pipeline.params import BACKGROUND_SUBTRACTION_ONLY, ProcessParams, with_overrides

    overrides: dict[str, Any] = {}
    if overrides_file is not None:
        overrides = json.loads(Path(overrides_file).read_text(encoding="utf-8"))
    if no_classifier:
        overrides = with_overrides(overrides, BACKGROUND_SUBTRACTION_ONLY)
    return ProcessParams().merged(overrides)


#: `SimulationConfig` fields of a lossless encoding: x264 at constant quality 0 keeps
#: the luma plane bit-exact (the chroma is still subsampled 4:2:0).
LOSSLESS: dict[str, Any] = {"codec": "h264", "crf": 0, "bits_per_pixel": None}


def is_lossless(config: dict[str, Any]) -> bool:
    """Whether a simulated recording's configuration (as in ``truth.json``) is lossless."""
    return all(config.get(key) == value for key, value in LOSSLESS.items())


def night_name(run: dict[str, Any]) -> str:
    """``<scenario> s<seed>``, with `` lossless`` for a lossless twin: a table row."""
    return f"{run['scenario']} s{run['seed']}{_twin_suffix(run)}"


def _twin_suffix(run: dict[str, Any]) -> str:
    return " lossless" if run.get("lossless") else ""


def simulation_configs(args: argparse.Namespace) -> list[SimulationConfig]:
    """One configuration per (scenario, seed) asked for; with ``--lossless-twin``, each
    followed by its lossless twin (`LOSSLESS`)."""
    from pipeline.simulate import SimulationConfig

    extra: dict[str, Any] = {}
    if args.sim_params is not None:
        extra = json.loads(Path(args.sim_params).read_text(encoding="utf-8"))
    shared = Path(__file__).resolve().parents[2] / "shared" / "data" / "real-3d" / "xyzt_tent.csv"
    configs = []
    for scenario in args.scenario or []:
        for seed in args.seeds:
            fields = {"scenario": scenario, "seed": seed, "seconds": args.seconds}
            fields |= {"width": args.width}
            if scenario == "real3d" and "real3d_csv" not in extra and shared.is_file():
                fields["real3d_csv"] = shared
            config = SimulationConfig(**(fields | extra))
            configs.append(config)
            if args.lossless_twin and not is_lossless(config.model_dump()):
                configs.append(SimulationConfig(**(config.model_dump() | LOSSLESS)))
    return configs


# -- recordings and runs ---------------------------------------------------------------------


def cached_recording(config: SimulationConfig, cache: Path, quiet: bool = True) -> Path:
    """Folder of ``config``'s simulated recording under ``cache``, rendered if absent."""
    from pipeline.simulate import simulate

    dump = config.model_dump(mode="json")
    name = f"{config.scenario}-seed{config.seed}-{config.width}px-{config.seconds:g}s"
    folder = cache / f"{name}-{_digest(dump)}"
    done = folder / "config.json"
    if done.is_file() and json.loads(done.read_text()) == dump:
        return folder
    if not quiet:
        print(f"simulating {name} into {folder}", file=sys.stderr, flush=True)
    simulate(config, folder)
    done.write_text(json.dumps(dump, indent=2) + "\n", encoding="utf-8")
    return folder


def load_truth_for_eval(recording: Path) -> GroundTruth:
    """The recording's truth; truth files written before the SNR/range columns (or the
    matched-filter SNR) existed get them recomputed from their configuration (checked
    to describe the same flashes)."""
    import numpy as np

    from pipeline.simulate import SimulationConfig, ground_truth, load_truth

    truth = load_truth(recording)
    f = truth.flashes
    complete = not (np.all(np.isnan(f.snr1)) or np.all(np.isnan(f.snr_mf1)))
    if len(f) == 0 or complete or "config" not in truth.extra:
        return truth
    fresh = ground_truth(SimulationConfig.model_validate(truth.extra["config"]))
    same = len(fresh.flashes) == len(f) and np.allclose(
        fresh.flashes.position(), f.position(), atol=1e-5
    )
    if not same:
        return truth  # a different simulator version: bins stay "unknown"
    return dataclasses.replace(truth, flashes=fresh.flashes)


def run_pipeline(
    recording: Path, truth: GroundTruth, out: Path, params: ProcessParams, reuse: bool
) -> str | None:
    """Run `pipeline.run.process` on a recording's videos into ``out``; the error
    (one line) when a stage fails, else None. With ``reuse``, a result folder made with
    the same parameters is kept."""
    from pipeline.run import process

    stamp = out / "eval-params.json"
    dump = params.model_dump(mode="json")
    if reuse and stamp.is_file() and json.loads(stamp.read_text()) == dump:
        return None
    cam1 = [recording / name for name in truth.extra.get("cam1", ["cam1_00.mp4"])]
    cam2 = [recording / name for name in truth.extra.get("cam2", ["cam2_00.mp4"])]
    out.mkdir(parents=True, exist_ok=True)
    # A stage that fails now must not leave an earlier run's results to be scored.
    for name in (
        "eval-params.json",
        artifacts.TRAJECTORIES_CSV,
        artifacts.CALIBRATION_JSON,
        artifacts.POINTS_NPZ,
        *(artifacts.flashes_name(c) for c in artifacts.CAMERAS),
        *(artifacts.candidates_name(c) for c in artifacts.CAMERAS),
    ):
        (out / name).unlink(missing_ok=True)
    try:
        process(cam1, cam2, truth.separation_m, out, params)
    except Exception as exc:  # a failed stage still leaves 2D results to score
        traceback.print_exc(limit=3, file=sys.stderr)
        return f"{type(exc).__name__}: {exc}"
    stamp.write_text(json.dumps(dump, indent=2) + "\n", encoding="utf-8")
    return None


def evaluate_night(
    recording: Path,
    results: Path | None,
    out_root: Path | None,
    params: ProcessParams,
    reuse: bool,
    log: Any = None,
    cuts: Sequence[float] = (),
) -> dict[str, Any]:
    """Run (unless ``results`` is given) and score one recording (at `cuts` too:
    `pipeline.detection_eval.cut_figures`)."""
    from pipeline.detection_eval import score_run
    from pipeline.evaluate import evaluate_run

    truth = load_truth_for_eval(recording)
    error = None
    if results is None:
        name = f"results-{_digest(params.model_dump(mode='json'))}"
        if out_root is not None:
            results = out_root / f"{recording.name}" / name
        else:
            results = recording / name
        if log:
            log(f"processing {recording.name} -> {results}")
        start = time.perf_counter()
        error = run_pipeline(recording, truth, results, params, reuse)
        if log:
            log(f"  done in {time.perf_counter() - start:.1f} s" + (f" ({error})" if error else ""))
    scores = score_run(results, truth, cuts)
    accuracy = None
    try:
        accuracy = evaluate_run(results, truth).to_dict()
    except (FileNotFoundError, ValueError, KeyError):
        accuracy = None
    return {
        "scenario": truth.scenario,
        "seed": truth.seed,
        "lossless": is_lossless(truth.extra.get("config", {})),
        "recording": str(recording),
        "results": str(results),
        "width": truth.width,
        "height": truth.height,
        "fps": truth.fps,
        "n_frames": {"cam1": truth.n_frames1, "cam2": truth.n_frames2},
        "error": error,
        **scores,
        "accuracy": accuracy,
    }


# -- the command -----------------------------------------------------------------------------


def _eval_detection(args: argparse.Namespace) -> int:
    from pipeline.detection_eval import (
        SCHEMA_VERSION,
        Row,
        bins_description,
        finite,
        format_bins,
        format_cuts,
        format_table,
        pool,
        tolerances,
    )

    if not args.scenario and not args.recording:
        print("error: give --scenario (to simulate) or --recording DIR", file=sys.stderr)
        return 2
    if args.results and len(args.results) != len(args.recording or []):
        print("error: give one --results per --recording", file=sys.stderr)
        return 2
    try:
        params = process_params(args.params, args.no_classifier)
        configs = simulation_configs(args)
    except ValidationError as exc:
        print(f"error: invalid parameters:\n{exc}", file=sys.stderr)
        return 2
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    def log(message: str) -> None:
        _log(args, message)

    jobs: list[tuple[Path, Path | None]] = []
    for config in configs:
        jobs.append((cached_recording(config, args.cache, quiet=args.quiet), None))
    for i, recording in enumerate(args.recording or []):
        jobs.append((recording, args.results[i] if args.results else None))

    runs = []
    for recording, results in jobs:
        try:
            runs.append(
                evaluate_night(
                    recording, results, args.out, params, args.reuse_results, log, args.cuts
                )
            )
        except (FileNotFoundError, ValueError) as exc:
            print(f"error: {recording}: {exc}", file=sys.stderr)
            return 1

    scenarios: dict[str, list[dict[str, Any]]] = {}
    for run in runs:
        scenarios.setdefault(run["scenario"] + _twin_suffix(run), []).append(run)
    pooled = {name: pool(group) for name, group in scenarios.items()}

    rows = [Row(night_name(r), r) for r in runs]
    rows += [Row(f"{name} (pooled)", p) for name, p in pooled.items() if p["n_runs"] > 1]
    print(format_table(rows))
    if args.cuts:
        print()
        print(format_cuts(rows))
    if args.bins:
        for row in rows:
            print()
            print(format_bins(row.name, row.entry))
    errors = [f"{night_name(r)}: {r['error']}" for r in runs if r["error"]]
    for line in errors:
        print(f"warning: pipeline failed on {line}", file=sys.stderr)
    if args.json:
        document = {
            "schema_version": SCHEMA_VERSION,
            "tolerances": tolerances(),
            "bins": bins_description(),
            "params": params.model_dump(mode="json"),
            "runs": runs,
            "pooled": pooled,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(finite(document), indent=1, allow_nan=False)
        args.json.write_text(text + "\n", encoding="utf-8")
    return 1 if errors else 0
