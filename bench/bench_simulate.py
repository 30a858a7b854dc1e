"""Simulator throughput: both cameras rendered in turn against at once (a process each).

Renders one simulated night (``--scenario``, ``--width``, ``--seconds``) ``--repeat``
times each way, alternating (the machine is shared), into a temporary folder; prints
the frames (of both cameras) per second of each way, their ratio within each round,
and whether the two ways wrote the same files byte for byte. Simulated nights are what
``eval-detection`` and ``train-acceptance`` spend most of their time on at 4K.

Run: ``.venv/bin/python bench/bench_simulate.py [--scenario hard-all] [--width 1280]``
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import tempfile
import time
from pathlib import Path

from pipeline.simulate import SimulationConfig, simulate


def render(config: SimulationConfig, out: Path, parallel: bool) -> tuple[float, dict[str, str]]:
    """Frames per second of one rendering, and the digest of each file it wrote."""
    start = time.perf_counter()
    simulate(config, out, parallel=parallel)
    seconds = time.perf_counter() - start
    digests = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(out.iterdir())}
    return 2 * config.n_frames / seconds, digests


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="hard-all")
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--seconds", type=float, default=4.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=2, help="rounds of the two ways")
    args = parser.parse_args(argv)

    config = SimulationConfig(
        scenario=args.scenario, seed=args.seed, width=args.width, seconds=args.seconds
    )
    print(f"{args.scenario} s{args.seed}, {config.width}×{config.height}, {config.n_frames} frames")
    print(f"cores: {os.cpu_count()}")
    rates: dict[bool, list[float]] = {False: [], True: []}
    files: dict[bool, dict[str, str]] = {}
    with tempfile.TemporaryDirectory(prefix="firefly3d-bench-sim-") as tmp:
        for round_ in range(args.repeat):
            for parallel in (False, True):
                fps, files[parallel] = render(config, Path(tmp) / f"{round_}-{parallel}", parallel)
                rates[parallel].append(fps)
    ratios = [b / a for a, b in zip(rates[False], rates[True], strict=True)]
    for parallel, label in ((False, "in turn"), (True, "at once")):
        rounds = ", ".join(f"{r:.1f}" for r in rates[parallel])
        print(f"{label:<8} {max(rates[parallel]):7.1f} frames/s (rounds {rounds})")
    rounds = ", ".join(f"{r:.2f}" for r in ratios)
    print(f"at once / in turn: {statistics.median(ratios):.2f} (rounds {rounds})")
    print(f"same files byte for byte: {files[False] == files[True]}")
    return 0 if files[False] == files[True] else 1


if __name__ == "__main__":
    raise SystemExit(main())
