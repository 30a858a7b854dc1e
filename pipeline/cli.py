"""The ``firefly3d`` command.

Sub-commands are registered by modules exposing ``register(subparsers)``: each adds
its parsers and sets ``func`` (``handler(args) -> int`` exit code) as a default.
Commands from other distributions of the project (the service's ``serve``, ``worker``,
``admin``) plug in through the ``firefly3d.commands`` entry-point group, so this
science package never imports service code.
"""

from __future__ import annotations

import os

# Our arrays are (N, 3) @ (3, 3): BLAS threads only add contention with the decoder and
# onnxruntime threads (25x slower on a loaded 2-core machine). Must precede numpy.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import sys
from collections.abc import Sequence
from importlib.metadata import entry_points

from pipeline import __version__

ENTRY_POINT_GROUP = "firefly3d.commands"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="firefly3d",
        description="3D firefly flash trajectories from stereo 360-degree videos.",
    )
    parser.add_argument("--version", action="version", version=f"firefly3d {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for register in _registrars():
        register(subparsers)
    return parser


def _registrars() -> list:
    from pipeline import acceptance_cli, classifier_cli, commands, detection_eval_cli

    registrars = [
        commands.register,
        classifier_cli.register,
        detection_eval_cli.register,
        acceptance_cli.register,
    ]
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            registrars.append(ep.load())
        except ImportError:
            # A plug-in whose optional dependencies are not installed (e.g. the service
            # without the `service` extra) must not break the science commands.
            continue
    return registrars


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
