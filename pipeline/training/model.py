"""The flash CNN (torch; imported only for training and export).

Design, from grouped cross-validation on the real phone patches plus simulated
hard cases (whole recordings held out; figures are out-of-fold ROC AUC on the real
recordings / on the four real recordings that hold both classes):

- plain 3-stage CNN, flattened head: 0.906 / 0.94 — it learns "dark surroundings =
  flash" because most real backgrounds are bright foliage, and fails on a held-out
  recording whose backgrounds are dim smudges in a dark sky (AUC 0.73 there);
- global average + max pooling head instead of flattening: 0.914 / 0.95;
- ring statistics alone (`RingStatistics` + small MLP): 0.948 / 0.97;
- CNN with global pooling + ring statistics (this model): 0.944 / 0.976 with the
  simulated data, and 0.995 on held-out simulated recordings.

The ring statistics give the head exposure-robust descriptors of the radial profile
(how sharp and how colourful the centre is compared with its surroundings) that a
few hundred labelled patches from twenty recordings cannot teach a CNN reliably.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional

#: Ring edges (pixels from the centre pixel) of `RingStatistics`.
RING_EDGES = (0.0, 1.5, 3.0, 5.0, 8.0, 12.0, float("inf"))


class RingStatistics(nn.Module):
    """Statistics of a patch over concentric rings about its centre pixel.

    Per ring (`RING_EDGES`): mean of ``log1p(v)`` for each colour channel, and of the
    luminance ``L`` (channel mean of ``v``, on the 0–255 scale): standard deviation
    and maximum of ``log1p(L)``, mean gradient magnitude ``log1p(|∂L|)`` (texture),
    and the share of pixels brighter than half the centre's 3×3 luminance (a soft
    step, so other bright spots count). 7 numbers per ring.

    Parameters
    ----------
    input_size : patch side in pixels.
    """

    per_ring = 7
    ring_mean: torch.Tensor
    ring_onehot: torch.Tensor
    ring_order: torch.Tensor

    def __init__(self, input_size: int) -> None:
        super().__init__()
        offsets = torch.arange(input_size, dtype=torch.float32) - input_size // 2
        radius = torch.hypot(offsets[:, None], offsets[None, :]).flatten()
        edges = torch.tensor(RING_EDGES)
        rings = ((radius >= edges[:-1, None]) & (radius < edges[1:, None])).float()  # (R, S²)
        sizes = rings.sum(dim=1)
        if (sizes == 0).any():
            raise ValueError(f"input_size {input_size} is too small for the rings {RING_EDGES}")
        # Every pixel lies in one ring: per-ring statistics are products with (S², R)
        # weights, and a ring's maximum is taken over its own pixels (`ring_order`, ring
        # by ring), never over R masked copies of the patch (4× the inference time).
        self.register_buffer("ring_mean", (rings / sizes[:, None]).T.contiguous())
        self.register_buffer("ring_onehot", rings)
        self.register_buffer("ring_order", torch.argsort(rings.argmax(dim=0), stable=True))
        self.ring_sizes = [int(n) for n in sizes]
        self.n_features = len(rings) * self.per_ring

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3, S, S) patches on the 0–1 scale -> (N, 7 × rings) statistics."""
        v = x * 255.0
        lum = v.mean(dim=1)
        c = lum.shape[-1] // 2
        centre = lum[:, c - 1 : c + 2, c - 1 : c + 2].mean(dim=(1, 2))
        gradient = functional.pad((lum[:, 1:, :] - lum[:, :-1, :]).abs(), (0, 0, 1, 0))
        gradient = gradient + functional.pad((lum[:, :, 1:] - lum[:, :, :-1]).abs(), (1, 0))
        bright = torch.sigmoid((lum - 0.5 * centre[:, None, None]) / 4.0)
        log_lum = torch.log1p(lum).flatten(1)  # (N, S²)

        colour = (torch.log1p(v).flatten(2) @ self.ring_mean).flatten(1)
        mean_log = log_lum @ self.ring_mean
        deviation = log_lum - mean_log @ self.ring_onehot  # from the mean of its own ring
        std_log = ((deviation**2) @ self.ring_mean + 1e-6).sqrt()  # finite gradient on flat rings
        by_ring = torch.split(log_lum[:, self.ring_order], self.ring_sizes, dim=1)
        max_log = torch.stack([ring.amax(dim=1) for ring in by_ring], dim=1)
        texture = torch.log1p(gradient.flatten(1) @ self.ring_mean)
        return torch.cat(
            [colour, std_log, max_log, texture, bright.flatten(1) @ self.ring_mean], dim=1
        )


class FlashNet(nn.Module):
    """Flash logit of an RGB patch centred on a bright blob.

    CNN trunk: 3×3 convolution + batch norm + ReLU stages of ``widths`` channels,
    2×2 max pooling after all but the last; its map is summarised by global average
    and max pooling. The head is one linear layer (after dropout) on those pooled
    features next to the batch-normalised `RingStatistics`.

    Parameters
    ----------
    input_size : patch side in pixels (at least 25, for the rings).
    widths : channels of the convolution stages.
    dropout : dropout before the linear head, during training.
    """

    def __init__(
        self, input_size: int, widths: tuple[int, ...] = (16, 32, 64), dropout: float = 0.2
    ) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        channels = 3
        for i, width in enumerate(widths):
            layers += [
                nn.Conv2d(channels, width, 3, padding=1, bias=False),
                nn.BatchNorm2d(width),
                nn.ReLU(inplace=True),
            ]
            if i < len(widths) - 1:
                layers.append(nn.MaxPool2d(2))
            channels = width
        self.trunk = nn.Sequential(*layers)
        self.rings = RingStatistics(input_size)
        self.ring_norm = nn.BatchNorm1d(self.rings.n_features)
        self.head = nn.Sequential(
            nn.Dropout(dropout), nn.Linear(2 * channels + self.rings.n_features, 1)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3, S, S) patches on the 0–1 scale -> (N,) flash logits."""
        maps = self.trunk(x)
        pooled = torch.cat([maps.mean(dim=(2, 3)), maps.amax(dim=(2, 3))], dim=1)
        features = torch.cat([pooled, self.ring_norm(self.rings(x))], dim=1)
        return self.head(features)[:, 0]


class CalibratedFlashNet(nn.Module):
    """A trained `FlashNet` with Platt scaling and the sigmoid: the shipped graph.

    Outputs the calibrated flash probability ``sigmoid(slope * logit + intercept)``,
    shape (N,).
    """

    slope: torch.Tensor
    intercept: torch.Tensor

    def __init__(self, net: FlashNet, slope: float = 1.0, intercept: float = 0.0) -> None:
        super().__init__()
        self.net = net
        self.register_buffer("slope", torch.tensor(float(slope)))
        self.register_buffer("intercept", torch.tensor(float(intercept)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3, S, S) scaled patches -> (N,) flash probabilities."""
        return torch.sigmoid(self.net(x) * self.slope + self.intercept)
