"""Classifier sub-commands of ``firefly3d``: train-classifier, eval-classifier, classify."""

from __future__ import annotations

import argparse
import csv
import shlex
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from tqdm import tqdm

if TYPE_CHECKING:  # the handlers import the classifier and the training code when they run
    import numpy as np

    from pipeline.classify import FlashClassifier

CHUNK = 4096  # images read per inference round in `classify`
REFERENCE_HELP = (
    "published model to compare with (card beside it or shipped), on the data folders "
    "whose patches are at least its input size"
)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``train-classifier``, ``eval-classifier`` and ``classify``."""
    _register_train(subparsers)
    _register_eval(subparsers)
    _register_classify(subparsers)
    _register_simulate_patches(subparsers)
    _register_procedural_patches(subparsers)


def _register_train(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train-classifier",
        help="train the flash CNN on labelled patch folders and export it as ONNX",
        description=(
            "Train the flash classifier on folders holding flash/ and background/ patches. "
            "Runs a grouped cross-validation (whole source recordings held out, from file "
            "names f-<video>-f<frame>x<x>y<y>.png; other names: one group per data folder), "
            "calibrates the probability and picks the threshold on the out-of-fold "
            "predictions, trains on everything, then writes MODEL.onnx and its card "
            "MODEL.json. Needs the 'train' extra (PyTorch)."
        ),
    )
    p.add_argument("--out", type=Path, required=True, metavar="MODEL.onnx")
    p.add_argument("--data", type=Path, action="append", required=True, metavar="DIR")
    p.add_argument("--epochs", type=int, default=15)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--cv-folds", type=int, default=5, metavar="K")
    p.add_argument("--input-size", type=int, default=33, metavar="S", help="patch side (px)")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument(
        "--reference-model", type=Path, default=None, metavar="ONNX", help=REFERENCE_HELP
    )
    p.add_argument(
        "--figures", type=Path, default=None, metavar="DIR",
        help="write the held-out reliability diagram and failure montage (PNG) here",
    )  # fmt: skip
    p.set_defaults(func=_train)


def _register_eval(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "eval-classifier",
        help="score a classifier on labelled patch folders against the baselines",
        description=(
            "ROC AUC, accuracy and precision/recall at the model's threshold, overall and "
            "per source recording, next to contrast features + logistic regression "
            "(grouped cross-validation on the same data) and, with --reference-model, a "
            "published reference network. Each data folder is reported separately."
        ),
    )
    p.add_argument("--model", type=Path, default=None, help="ONNX model (default: shipped)")
    p.add_argument("--card", type=Path, default=None, help="model card (default: beside)")
    p.add_argument("--data", type=Path, action="append", required=True, metavar="DIR")
    p.add_argument("--cv-folds", type=int, default=5, metavar="K", help="for the baseline")
    p.add_argument(
        "--reference-model", type=Path, default=None, metavar="ONNX", help=REFERENCE_HELP
    )
    p.add_argument(
        "--figures", type=Path, default=None, metavar="DIR",
        help="write the reliability diagram and failure montage (PNG) here",
    )  # fmt: skip
    p.set_defaults(func=_evaluate)


def _register_classify(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "classify",
        help="flash probability of image patches -> CSV",
        description=(
            "Score image patches (.png/.jpg/.jpeg; folders are searched recursively) "
            "centred on a blob's brightest pixel. Patches of another size than the "
            "model's are CENTRE-CROPPED when larger and EDGE-PADDED (border pixels "
            "replicated) when smaller. Writes CSV columns path,flash_probability. "
            "Unreadable images are reported on stderr and skipped; the exit status is 1 "
            "only when no image at all could be scored."
        ),
    )
    p.add_argument("paths", type=Path, nargs="+", metavar="PATH")
    p.add_argument("--model", type=Path, default=None, help="ONNX model (default: shipped)")
    p.add_argument("--card", type=Path, default=None, help="model card (default: beside)")
    p.add_argument("--out", type=Path, required=True, metavar="scores.csv")
    p.add_argument(
        "--batch-size", type=int, help="patches per inference call (default: the runtime's)"
    )
    p.set_defaults(func=_classify)


def _register_simulate_patches(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "simulate-patches",
        help="labelled training patches from simulated recordings (hard cases)",
        description=(
            "Simulate a recording per scenario and seed, track camera 1 as in production "
            "and label every candidate against the ground truth (flash within 2 px of a "
            "visible true flash, background beyond 5 px, dropped in between). Writes "
            "DIR/flash, DIR/background (files f-sim<scenario><seed>-f<frame>x<x>y<y>.png) "
            "and DIR/simulated.json describing how they were made."
        ),
    )
    p.add_argument("--out", type=Path, required=True, metavar="DIR")
    p.add_argument("--scenario", action="append", help="repeatable (default: all but real3d)")
    p.add_argument("--seed", type=int, action="append", help="repeatable (default: 101-104)")
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--size", type=int, default=65, help="patch side (px)")
    p.add_argument("--max-flash", type=int, default=150, help="per recording")
    p.add_argument("--max-background", type=int, default=300, help="per recording")
    p.add_argument(
        "--hard-negatives",
        type=Path,
        metavar="MODEL.onnx",
        help="draw half of the backgrounds weighted by this classifier's flash probability",
    )
    p.set_defaults(func=_simulate_patches)


def _register_procedural_patches(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "procedural-patches",
        help="domain-randomised labelled patches (flashes and hard negatives), in seconds",
        description=(
            "Render flash and hard-negative patches directly (no video): flash peak from "
            "the noise floor to saturation, point spread 0.6-2 px, motion streaks, colour "
            "yellow-green to white, backgrounds black sky to bright foliage; negatives are "
            "foliage glints, lamps, headlights, the moon through leaves and out-of-focus "
            "blobs. Each pseudo-recording (group synth<seed>r<k>) has its own white "
            "balance, gamma, grain and compression. Writes DIR/flash, DIR/background and "
            "DIR/synthetic.json."
        ),
    )
    p.add_argument("--out", type=Path, required=True, metavar="DIR")
    p.add_argument("--recordings", type=int, default=12)
    p.add_argument("--per-recording", type=int, default=600)
    p.add_argument("--size", type=int, default=65, help="patch side (px)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_procedural_patches)


def _procedural_patches(args: argparse.Namespace) -> int:
    from pipeline.training.simdata import build_procedural_dataset

    manifest = build_procedural_dataset(
        args.out, args.recordings, args.per_recording, args.size, args.seed
    )
    print(
        f"wrote {manifest['n_flash']} flash and {manifest['n_background']} background "
        f"patches to {args.out}"
    )
    return 0


def _train(args: argparse.Namespace) -> int:
    from pipeline.classify import FlashClassifier
    from pipeline.training.dataset import load_patch_folder

    try:
        from pipeline.training.trainer import TrainConfig
        from pipeline.training.workflow import train_classifier
    except ImportError as exc:
        print(
            f"train-classifier needs PyTorch ({exc}): pip install 'firefly3d[train]'",
            file=sys.stderr,
        )
        return 1
    if args.epochs < 1:
        print("--epochs must be at least 1", file=sys.stderr)
        return 2
    try:
        parts = [load_patch_folder(d) for d in args.data]
        reference = FlashClassifier.load(args.reference_model) if args.reference_model else None
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    config = TrainConfig(epochs=args.epochs, seed=args.seed, threads=args.threads)
    provenance = {
        "data": [str(d) for d in args.data],
        "command": _train_command(args),
        "data_manifests": _manifests(args.data),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with tqdm(total=(args.cv_folds + 1) * args.epochs, unit="epoch", desc="training") as bar:
        try:
            run = train_classifier(
                parts, args.out, config, args.cv_folds, args.input_size, provenance,
                reference, bar.update, args.figures,
            )  # fmt: skip
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
    print(run.report)
    print(
        f"\nwrote {args.out} and {args.out.with_suffix('.json')} (threshold "
        f"{run.card.threshold:.3f}; onnxruntime vs torch max difference {run.export_error:.1e})"
    )
    return 0


def _manifests(folders: Sequence[Path]) -> dict[str, object]:
    """How generated data folders were made (their ``simulated.json``), by folder."""
    from pipeline.training.dataset import folder_manifest

    return {str(d): folder_manifest(d) for d in folders}


def _train_command(args: argparse.Namespace) -> str:
    """The canonical command line that reproduces this training run."""
    words = ["firefly3d", "train-classifier", "--out", str(args.out)]
    for d in args.data:
        words += ["--data", str(d)]
    words += [
        "--epochs", str(args.epochs), "--seed", str(args.seed),
        "--cv-folds", str(args.cv_folds), "--input-size", str(args.input_size),
        "--threads", str(args.threads),
    ]  # fmt: skip
    if args.reference_model:
        words += ["--reference-model", str(args.reference_model)]
    return shlex.join(words)


def _evaluate(args: argparse.Namespace) -> int:
    import numpy as np

    from pipeline.classify import FlashClassifier, default_model_path
    from pipeline.training.dataset import PatchSet, load_patch_folder
    from pipeline.training.evaluation import (
        Predictions,
        baseline_predictions,
        compare,
        failure_montage,
        format_comparison,
        format_summary,
        held_out_summary,
        plot_reliability,
        reference_predictions,
    )
    from pipeline.training.splits import grouped_folds

    try:
        classifier = FlashClassifier.load(args.model, args.card, threads=None)
        parts = [load_patch_folder(d) for d in args.data]
        patches = PatchSet.concat([p.resized(classifier.input_size) for p in parts])
        models = [
            Predictions(
                classifier.card.name, classifier.predict(patches.images), classifier.threshold
            )
        ]
        if len(np.unique(patches.groups)) >= args.cv_folds:
            folds = grouped_folds(patches.groups, patches.strata(), args.cv_folds)
            models.append(baseline_predictions(patches, folds))
        else:
            print("too few recordings for the grouped-CV baseline; skipped", file=sys.stderr)
        if args.reference_model:
            models.append(reference_predictions(FlashClassifier.load(args.reference_model), parts))
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    seen = _training_folders(classifier) & {d.resolve() for d in args.data}
    for folder in sorted(seen):
        print(f"warning: {folder} was used to train this model: not held-out figures")
    model = args.model or default_model_path()
    title = f"{model} at threshold {classifier.threshold:.3f}"
    print(format_comparison(compare(patches, models), title))
    summary = held_out_summary(patches, models[0].probabilities, classifier.threshold)
    print()
    print(format_summary(summary, classifier.threshold, f"{classifier.card.name} by data source"))
    if args.figures is not None:
        args.figures.mkdir(parents=True, exist_ok=True)
        name = classifier.card.name
        plot_reliability(summary, args.figures / f"{name}-eval-reliability.png", name)
        failure_montage(
            patches, models[0].probabilities, classifier.threshold,
            args.figures / f"{name}-eval-failures.png",
        )  # fmt: skip
    return 0


def _training_folders(classifier: FlashClassifier) -> set[Path]:
    """Data folders the card says the model was trained on (relative to the cwd)."""
    return {Path(d).resolve() for d in classifier.card.training.get("data", [])}


def _simulate_patches(args: argparse.Namespace) -> int:
    from pipeline.training.simdata import (
        DEFAULT_SCENARIOS,
        DEFAULT_SEEDS,
        build_simulated_dataset,
    )

    scenarios = args.scenario or DEFAULT_SCENARIOS
    seeds = args.seed or DEFAULT_SEEDS
    with tqdm(total=len(scenarios) * len(seeds), unit="recording", desc="simulate") as bar:
        try:
            manifest = build_simulated_dataset(
                args.out, scenarios, seeds, args.seconds, args.width, args.size,
                args.max_flash, args.max_background, args.hard_negatives, bar.update,
            )  # fmt: skip
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
    recordings = manifest["recordings"]
    assert isinstance(recordings, list)
    flashes = sum(r["flash_kept"] for r in recordings)
    backgrounds = sum(r["background_kept"] for r in recordings)
    print(f"wrote {flashes} flash and {backgrounds} background patches to {args.out}")
    return 0


def _classify(args: argparse.Namespace) -> int:
    from pipeline.classify import DEFAULT_BATCH, FlashClassifier

    try:
        batch_size = args.batch_size or DEFAULT_BATCH
        classifier = FlashClassifier.load(
            args.model, args.card, batch_size=batch_size, threads=None
        )
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    files = list(_image_files(args.paths))
    scored = skipped = 0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with (
        args.out.open("w", newline="") as stream,
        tqdm(total=len(files), unit="img", desc="classify", disable=len(files) < CHUNK) as bar,
    ):
        writer = csv.writer(stream)
        writer.writerow(["path", "flash_probability"])
        for start in range(0, len(files), CHUNK):
            chunk = files[start : start + CHUNK]
            names, patches = _read_patches(chunk, classifier.input_size)
            probabilities = classifier.predict(patches)
            writer.writerows((n, f"{p:.6f}") for n, p in zip(names, probabilities, strict=True))
            scored += len(names)
            skipped += len(chunk) - len(names)
            bar.update(len(chunk))
    missing = sum(1 for p in args.paths if not p.exists())
    print(f"scored {scored} images, skipped {skipped + missing}; wrote {args.out}", file=sys.stderr)
    return 0 if scored else 1


def _image_files(paths: Sequence[Path]) -> Iterator[Path]:
    from pipeline.training.dataset import find_images

    for path in paths:
        if not path.exists():
            print(f"skipped {path}: no such file or folder", file=sys.stderr)
            continue
        yield from find_images(path)


def _read_patches(files: Sequence[Path], size: int) -> tuple[list[str], np.ndarray]:
    """Readable images among ``files``, cropped/padded to ``size``; reports the others."""
    import numpy as np

    from pipeline.classify import center_crop_or_pad
    from pipeline.training.dataset import read_rgb

    names, patches = [], []
    for path in files:
        image = read_rgb(path)
        if image is None:
            print(f"skipped {path}: not a readable image", file=sys.stderr)
            continue
        names.append(str(path))
        patches.append(center_crop_or_pad(image[None], size)[0])
    stacked = np.stack(patches) if patches else np.zeros((0, size, size, 3), np.uint8)
    return names, stacked
