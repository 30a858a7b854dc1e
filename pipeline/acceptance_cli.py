"""``firefly3d train-acceptance``: fit the evidence model on simulated nights.

The nights are the runs of ``firefly3d eval-detection --json`` files (each run names
its recording, with ground truth, and its result folder), so the same cached
simulations and pipeline runs serve both the measurement and the training.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``train-acceptance``."""
    parser = subparsers.add_parser(
        "train-acceptance",
        help="fit the evidence model (final acceptance) on simulated nights with ground truth",
        description="Fit the evidence model (pipeline.evidence_model) on the candidates of "
        "the runs listed in eval-detection JSON files: a first pass, then a second that "
        "also reads the first's out-of-fold probabilities of each candidate's light curve "
        "and stereo match. Choose its threshold on the second pass's out-of-fold "
        "predictions (folds of whole seeds) and write the model file. Needs the train "
        "extra (scikit-learn).",
    )
    parser.add_argument(
        "--runs", type=Path, nargs="+", required=True, metavar="JSON", help="eval-detection --json"
    )
    parser.add_argument("--out", type=Path, required=True, metavar="FILE", help="model JSON")
    parser.add_argument("--seed", type=int, default=0)
    cut = parser.add_mutually_exclusive_group()
    cut.add_argument(
        "--threshold",
        type=float,
        default=None,
        metavar="P",
        help="keep this flash-probability cut (e.g. the shipped model's) instead of the one "
        "of largest out-of-fold F1, which moves with the mix of nights: many easy nights "
        "pull it down",
    )
    cut.add_argument(
        "--false-as-first-pass-at",
        type=float,
        default=None,
        metavar="P",
        help="cut where the two passes accept, out of fold, as many false candidates as the "
        "first pass alone at P: a one-pass operating point's false count, kept",
    )
    parser.add_argument(
        "--classifier",
        default=None,
        metavar="NAME",
        help="file name of the patch classifier the runs used (default: the shipped one)",
    )
    parser.set_defaults(func=_train_acceptance)


def _train_acceptance(args: argparse.Namespace) -> int:
    from pipeline.classify import DEFAULT_MODEL_NAME
    from pipeline.detection_eval_cli import load_truth_for_eval
    from pipeline.training.acceptance import common_tracking, night_rows, run_params, train

    nights, params = [], []
    for document in args.runs:
        for run in json.loads(document.read_text(encoding="utf-8"))["runs"]:
            if run.get("error"):
                print(f"skipping {run['results']}: {run['error']}", file=sys.stderr)
                continue
            results = Path(run["results"])
            truth = load_truth_for_eval(Path(run["recording"]))
            params.append(run_params(results))
            nights.append(night_rows(results, truth, params[-1]))
            print(f"{nights[-1].name}: {len(nights[-1].is_flash)} candidates", file=sys.stderr)
    if len({n.seed for n in nights}) < 2:
        print("error: give nights of at least two seeds (folds are whole seeds)", file=sys.stderr)
        return 2
    try:
        tracking = common_tracking(params)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    classifier = args.classifier or DEFAULT_MODEL_NAME
    model, figures = train(
        nights,
        classifier,
        tracking,
        args.seed,
        args.threshold,
        first_pass_cut=args.false_as_first_pass_at,
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    model.to_json(args.out)
    chosen = model.card["threshold_chosen_by"]
    print(f"threshold {model.threshold:.3f} ({chosen}); out of fold at it:")
    print(f"{'nights':26s} {'accepted':>9s} {'true':>7s} {'precision':>9s} {'recall':>7s}")
    first = model.card["first_pass_out_of_fold_at_threshold"]
    for name, f in [*figures.items(), ("(first pass alone, all)", first)]:
        precision, recall = (
            "-" if math.isnan(v) else f"{v:.3f}"
            for v in (f["precision"], f["recall_of_candidates"])
        )
        print(f"{name:26s} {f['accepted']:9d} {f['true']:7d} {precision:>9s} {recall:>7s}")
    print(f"wrote {args.out}")
    return 0
