"""Simulated flash patches against the real labelled ones: blob size, contrast, colour.

Measures (`pipeline.simulation.patchstats`) the real flash patches of
``../shared/data/ffeye-gp360-65`` (GoPro 360) and ``ffeye-phone-33`` (phones) and the
decoded flash patches of simulated recordings (brightest pixel at the centre, as in the
real sets; isolated flash-frames with peak SNR >= 5), and prints the 10th/50th/90th
percentiles of each figure side by side. The real sets were labelled by hand, so they
hold visible flashes (GoPro contrast 60-210): the simulated rows are also shown
restricted to contrast >= 40.

    .venv/bin/python bench/sim_vs_real_patches.py [--scenarios clean hard-clean]
        [--width 1280] [--seconds 8] [--seed 1] [--cache DIR]
"""

from __future__ import annotations

import argparse
import glob
import tempfile
from pathlib import Path

import cv2
import numpy as np

from pipeline.detection_eval_cli import cached_recording
from pipeline.simulate import SimulationConfig, load_truth
from pipeline.simulation.patchstats import STATS, patch_stats, simulated_flash_patches

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def real_patches(folder: Path) -> np.ndarray:
    """The flash patches of a real set, RGB uint8 (N, S, S, 3)."""
    paths = sorted(glob.glob(str(folder / "flash" / "*.png")))
    return np.stack([cv2.imread(p, cv2.IMREAD_COLOR)[:, :, ::-1] for p in paths])


def summary(name: str, stats: dict[str, np.ndarray]) -> str:
    n = len(stats["contrast"])
    cells = []
    for key in STATS:
        if n:
            p10, p50, p90 = np.percentile(stats[key], [10, 50, 90])
            cells.append(f"{p10:6.2f} {p50:6.2f} {p90:6.2f}")
        else:
            cells.append(f"{'-':>20}")
    return f"{name:<30} {n:>5}  " + "  ".join(cells)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=["clean", "hard-clean", "hard-wind"])
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--cache", type=Path, help="keep the recordings here (default: temp)")
    args = parser.parse_args()

    header = f"{'patches':<30} {'n':>5}  " + "  ".join(f"{key + ' p10/50/90':>20}" for key in STATS)
    lines = [header, "-" * len(header)]
    for name in ("ffeye-gp360-65", "ffeye-phone-33"):
        folder = SHARED / name
        if folder.is_dir():
            lines.append(summary(f"real {name}", patch_stats(real_patches(folder))))
    with tempfile.TemporaryDirectory() as tmp:
        cache = args.cache or Path(tmp)
        for scenario in args.scenarios:
            config = SimulationConfig(
                scenario=scenario, seed=args.seed, seconds=args.seconds, width=args.width
            )
            recording = cached_recording(config, cache)
            truth = load_truth(recording)
            patches, _ = simulated_flash_patches(recording, truth, camera=1, size=33)
            stats = patch_stats(patches)
            label = f"sim {scenario} {args.width}px"
            lines.append(summary(label, stats))
            bright = stats["contrast"] >= 40
            lines.append(summary("  contrast >= 40", {k: v[bright] for k, v in stats.items()}))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
