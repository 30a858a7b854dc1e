"""Inference speed of the flash classifier: patches per second of `FlashClassifier.predict`.

Prints, for several batch sizes and onnxruntime intra-op thread counts, the patches/s
of the batched session (card preprocessing included) and its ratio to one-patch-per-call
inference measured in the same run, then the same for an older model (``--compare``,
by default the previous shipped ``flashnet33.onnx``) and the speed ratio of the two at
the runtime's default batch and thread count (1). Target on the 2-core reference machine:
≥ 5,000 patches/s.

    .venv/bin/python bench/bench_classifier.py [--model MODEL.onnx] [--seconds 2]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from pipeline.classify import DEFAULT_BATCH, MODELS_DIR, FlashClassifier

PREVIOUS_MODEL = MODELS_DIR / "flashnet33.onnx"


def night_patches(n: int, size: int, seed: int = 0) -> np.ndarray:
    """Dark noisy RGB patches with a yellow-green dot in the centre (uint8)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size] - size // 2
    dot = np.exp(-(yy**2 + xx**2) / 3.0)[None, :, :, None] * [180, 220, 70]
    noise = rng.normal(15, 4, (n, size, size, 3))
    return np.clip(noise + dot * rng.uniform(0.3, 1.0, (n, 1, 1, 1)), 0, 255).astype(np.uint8)


def patches_per_second(classifier: FlashClassifier, patches: np.ndarray, seconds: float) -> float:
    """Throughput of ``classifier.predict`` over repeated calls on ``patches``."""
    classifier.predict(patches[: classifier.batch_size])  # warm-up: allocations, kernels
    done, start = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        classifier.predict(patches)
        done += len(patches)
    return done / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, default=None, help="default: shipped model")
    parser.add_argument("--seconds", type=float, default=2.0, help="per measurement")
    parser.add_argument(
        "--compare", type=Path, default=PREVIOUS_MODEL, help="older model to compare with"
    )
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} logical cores\n")
    rate = table(args.model, args.seconds)
    if args.compare is not None and args.compare.is_file():
        print()
        old = table(args.compare, args.seconds)
        print(
            f"\nspeed ratio, batch {DEFAULT_BATCH}, 1 thread: {rate / old:.2f} "
            f"({rate:.0f} vs {old:.0f} patches/s of {args.compare.name})"
        )


def table(model: Path | None, seconds: float) -> float:
    """Print one model's table; return its patches/s at the default batch and 1 thread."""
    probe = FlashClassifier.load(model)
    patches = night_patches(4096, probe.input_size)
    print(f"model {probe.card.name}: {probe.input_size}x{probe.input_size} RGB patches")
    single = FlashClassifier.load(model, batch_size=1, threads=1)
    base = patches_per_second(single, patches[:256], seconds)
    print(f"baseline, one patch per call, 1 thread: {base:9.0f} patches/s")
    print(f"{'threads':>7s} {'batch':>6s} {'patches/s':>10s} {'x baseline':>10s}")
    default = 0.0
    for threads in (1, 2):
        for batch in (64, 256, 1024, 4096):
            classifier = FlashClassifier.load(model, batch_size=batch, threads=threads)
            rate = patches_per_second(classifier, patches, seconds)
            print(f"{threads:7d} {batch:6d} {rate:10.0f} {rate / base:10.1f}")
            if threads == 1 and batch == DEFAULT_BATCH:
                default = rate
    return default


if __name__ == "__main__":
    main()
