"""Batch augmentation of training patches (torch, vectorised over the batch).

Each transform models a nuisance that differs between recordings while the label
stays the same: orientation of the blob's motion streak (dihedral flips/rotations),
exposure and white balance (brightness and per-channel gain), focus and motion
(blur), centring error of the brightest pixel (±1 px shift) and sensor/compression
noise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import torch
from torch.nn import functional as F


@dataclass(frozen=True)
class AugmentConfig:
    """Magnitudes of the random transforms (0 disables one).

    Attributes
    ----------
    dihedral : apply a random one of the 8 flips/90° rotations.
    brightness : log-gain spread, uniform in [-b, b], applied to all channels.
    colour : log-gain spread per channel, normal with this standard deviation.
    blur : probability of a 3×3 Gaussian blur (sigma 0.8 px).
    shift : probability of a random shift by one pixel in x and/or y.
    noise : largest standard deviation of additive Gaussian noise (0–1 scale).
    streak : probability of a 5-pixel motion streak (horizontal or diagonal before the
        random flips, so any of 4 directions), rescaled to the patch's former peak as
        a fast firefly near the camera draws a saturated line.
    saturation : spread of the colour saturation: each patch is mixed with its grey
        by a factor ``exp(U(-s, s/2))`` (cameras differ most in how saturated a
        flash looks: GoPro flashes are near white, phone ones yellow-green).
    """

    dihedral: bool = True
    brightness: float = 0.5
    colour: float = 0.1
    blur: float = 0.2
    shift: float = 0.3
    noise: float = 0.02
    streak: float = 0.2
    saturation: float = 0.5


NO_AUGMENT = AugmentConfig(
    dihedral=False, brightness=0, colour=0, blur=0, shift=0, noise=0, streak=0, saturation=0
)
_STREAK_LENGTH = 5
_STREAK_KERNELS = (
    torch.stack(
        [
            torch.zeros(_STREAK_LENGTH, _STREAK_LENGTH).index_fill_(0, torch.tensor(2), 1.0),
            torch.eye(_STREAK_LENGTH),
        ]
    )
    / _STREAK_LENGTH
)

_BLUR = torch.tensor([0.2, 0.6, 0.2])  # ~Gaussian, sigma 0.8 px, sampled at -1, 0, 1


def augment(x: torch.Tensor, config: AugmentConfig, generator: torch.Generator) -> torch.Tensor:
    """Randomly transformed copy of (N, 3, S, S) patches scaled to [0, 1]."""
    n = len(x)

    def draw(p: float) -> torch.Tensor:
        return torch.rand(n, generator=generator) < p

    if config.streak:
        selected, diagonal = draw(config.streak), draw(0.5)
        for k, kernel in enumerate(_STREAK_KERNELS):
            x = _apply(x, selected & (diagonal == bool(k)), partial(_streak, kernel=kernel))
    if config.dihedral:
        x = _apply(x, draw(0.5), lambda v: v.flip(3))
        x = _apply(x, draw(0.5), lambda v: v.flip(2))
        x = _apply(x, draw(0.5), lambda v: v.transpose(2, 3))
    if config.shift:
        offsets = torch.randint(-1, 2, (2, n), generator=generator)
        selected = draw(config.shift)
        x = _apply(x, selected, lambda v: _shift(v, offsets[:, selected]))
    if config.blur:
        x = _apply(x, draw(config.blur), _blur)
    log_gain = (torch.rand(n, 1, 1, 1, generator=generator) * 2 - 1) * config.brightness
    log_gain = log_gain + torch.randn(n, 3, 1, 1, generator=generator) * config.colour
    x = x * torch.exp(log_gain)
    if config.saturation:
        u = torch.rand(n, 1, 1, 1, generator=generator)
        factor = torch.exp((u * 1.5 - 1.0) * config.saturation)
        grey = x.mean(dim=1, keepdim=True)
        x = grey + factor * (x - grey)
    sigma = torch.rand(n, 1, 1, 1, generator=generator) * config.noise
    x = x + torch.randn(x.shape, generator=generator) * sigma
    return x.clamp(0.0, 1.0)  # the sensor saturates


def _apply(
    x: torch.Tensor, selected: torch.Tensor, transform: Callable[[torch.Tensor], torch.Tensor]
) -> torch.Tensor:
    """``x`` with ``transform`` applied to the selected patches only (cheaper than all)."""
    if not selected.any():
        return x
    out = x.clone()
    out[selected] = transform(x[selected])
    return out


def _streak(x: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """Smear patches along the kernel's line; a gain restores the peak (at most 4x)."""
    pad = _STREAK_LENGTH // 2
    padded = F.pad(x, (pad, pad, pad, pad), mode="replicate")
    smeared = F.conv2d(padded, kernel.to(x.dtype).expand(3, 1, -1, -1), groups=3)
    peak = x.amax(dim=(1, 2, 3), keepdim=True)
    gain = (peak / smeared.amax(dim=(1, 2, 3), keepdim=True).clamp(min=1e-6)).clamp(1.0, 4.0)
    return (smeared * gain).clamp(0.0, 1.0)


def _blur(x: torch.Tensor) -> torch.Tensor:
    kernel = (_BLUR[:, None] * _BLUR[None, :]).to(x.dtype).expand(3, 1, 3, 3)
    return F.conv2d(F.pad(x, (1, 1, 1, 1), mode="replicate"), kernel, groups=3)


def _shift(x: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """Move patch i by ``offsets[:, i]`` (rows, columns; each -1, 0 or 1), edge replicated."""
    padded = F.pad(x, (1, 1, 1, 1), mode="replicate").permute(0, 2, 3, 1)
    index = torch.arange(x.shape[-1]) + 1
    rows, cols = index + offsets[0][:, None], index + offsets[1][:, None]  # (N, S) each
    batch = torch.arange(len(x))[:, None, None]
    return padded[batch, rows[:, :, None], cols[:, None, :]].permute(0, 3, 1, 2)
