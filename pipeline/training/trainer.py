"""Training loop, out-of-fold prediction and ONNX export of `FlashNet` (torch)."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from pipeline.training.augment import AugmentConfig, augment
from pipeline.training.calibration import Platt
from pipeline.training.dataset import PatchSet
from pipeline.training.model import CalibratedFlashNet, FlashNet

#: Network input = raw 0–255 value × SCALE (written to the model card).
SCALE = 1.0 / 255.0
ONNX_INPUT, ONNX_OUTPUT, ONNX_OPSET = "patches", "flash_probability", 17


@dataclass(frozen=True)
class TrainConfig:
    """Hyper-parameters of one training run (all recorded in the model card).

    ``balance`` gives every data source (folder) the same share of the loss whatever
    its size, so thousands of simulated patches do not drown the one real GoPro
    recording; within a source the classes are balanced by the square root of their
    counts (a class of 28 patches next to 1,289 gets 13 % of its source's weight, not
    half: 28 near-duplicates weighted 46-fold would be memorised, not learnt).
    """

    epochs: int = 15
    batch_size: int = 64
    learning_rate: float = 3e-3
    weight_decay: float = 1e-4
    widths: tuple[int, ...] = (16, 32, 64)
    dropout: float = 0.2
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    balance: bool = True
    seed: int = 0
    threads: int = 1


def seed_everything(seed: int, threads: int) -> None:
    """Make torch reproducible: fixed seed, deterministic kernels, fixed thread count."""
    torch.manual_seed(seed)
    torch.use_deterministic_algorithms(True)
    torch.set_num_threads(threads)


def to_tensor(images: np.ndarray) -> torch.Tensor:
    """uint8 (N, S, S, 3) RGB -> float32 (N, 3, S, S) scaled by `SCALE`."""
    return torch.from_numpy(images).permute(0, 3, 1, 2).float() * SCALE


def train_model(
    patches: PatchSet,
    config: TrainConfig,
    progress: Callable[[int], None] | None = None,
) -> FlashNet:
    """Train a `FlashNet` on all ``patches``; deterministic given ``config.seed``.

    AdamW with a one-cycle learning-rate schedule, binary cross-entropy on the logit,
    fresh augmentation (`augment`) of every batch. ``progress(1)`` after each epoch.
    """
    seed_everything(config.seed, config.threads)
    generator = torch.Generator().manual_seed(config.seed)
    model = FlashNet(patches.size, config.widths, config.dropout)
    x = to_tensor(patches.images)
    y = torch.from_numpy(patches.labels.astype(np.float32))
    weight = torch.from_numpy(sample_weights(patches.sources, patches.labels, config.balance))
    steps = max(1, -(-len(y) // config.batch_size))
    optimizer = torch.optim.AdamW(
        model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    schedule = torch.optim.lr_scheduler.OneCycleLR(
        optimizer, max_lr=config.learning_rate, total_steps=config.epochs * steps
    )
    model.train()
    for _ in range(config.epochs):
        order = torch.randperm(len(y), generator=generator)
        for batch in order.split(config.batch_size):
            logits = model(augment(x[batch], config.augment, generator))
            loss = F.binary_cross_entropy_with_logits(logits, y[batch], weight=weight[batch])
            optimizer.zero_grad()
            (loss * len(batch) / weight[batch].sum()).backward()
            optimizer.step()
            schedule.step()
        if progress:
            progress(1)
    return model.eval()


def sample_weights(sources: np.ndarray, labels: np.ndarray, balance: bool) -> np.ndarray:
    """Per-sample loss weights, mean 1 (see `TrainConfig`): every source the same total,
    its classes weighted by the square root of their counts, if ``balance``."""
    if not balance:
        return np.ones(len(labels), dtype=np.float32)
    _, source_of = np.unique(sources, return_inverse=True)
    w = np.zeros(len(labels))
    for s in range(source_of.max() + 1):
        rows = source_of == s
        counts = {c: int((labels[rows] == c).sum()) for c in np.unique(labels[rows])}
        share = {c: np.sqrt(n) for c, n in counts.items()}
        total = sum(share.values())
        for c, n in counts.items():
            w[rows & (labels == c)] = share[c] / total / n
    return (w * len(w) / w.sum()).astype(np.float32)


@torch.no_grad()
def predict_logits(model: FlashNet, images: np.ndarray, batch_size: int = 1024) -> np.ndarray:
    """Flash logits (float64, (N,)) of uint8 (N, S, S, 3) RGB patches."""
    model.eval()
    out = [model(to_tensor(images[i : i + batch_size])) for i in range(0, len(images), batch_size)]
    return torch.cat(out).double().numpy() if out else np.zeros(0)


def out_of_fold_logits(
    patches: PatchSet,
    folds: Sequence[tuple[np.ndarray, np.ndarray]],
    config: TrainConfig,
    progress: Callable[[int], None] | None = None,
) -> np.ndarray:
    """Logit of every patch from the model trained on the folds that exclude it."""
    logits = np.full(len(patches), np.nan)
    for train, test in folds:
        model = train_model(patches.subset(train), config, progress)
        logits[test] = predict_logits(model, patches.images[test])
    return logits


def export_onnx(model: FlashNet, calibration: Platt, path: str | Path, input_size: int) -> None:
    """Write the calibrated network (outputs the probability) as ONNX, dynamic batch.

    Input ``patches`` float32 (N, 3, S, S) = raw RGB × `SCALE`; output
    ``flash_probability`` float32 (N,).
    """
    calibrated = CalibratedFlashNet(model, calibration.slope, calibration.intercept).eval()
    example = torch.zeros(1, 3, input_size, input_size)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter warns it is legacy
        torch.onnx.export(
            calibrated,
            (example,),
            str(path),
            dynamo=False,
            input_names=[ONNX_INPUT],
            output_names=[ONNX_OUTPUT],
            dynamic_axes={ONNX_INPUT: {0: "batch"}, ONNX_OUTPUT: {0: "batch"}},
            opset_version=ONNX_OPSET,
        )


@torch.no_grad()
def torch_probabilities(model: FlashNet, calibration: Platt, images: np.ndarray) -> np.ndarray:
    """What the exported graph should output for ``images``: the torch reference."""
    net = CalibratedFlashNet(model, calibration.slope, calibration.intercept).eval()
    return net(to_tensor(images)).numpy()
