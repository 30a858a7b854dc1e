import itertools

import numpy as np
import pytest
import torch

from pipeline.training.model import RING_EDGES, CalibratedFlashNet, FlashNet, RingStatistics

N_RINGS = len(RING_EDGES) - 1


def split(stats: torch.Tensor) -> dict[str, torch.Tensor]:
    """Named (N, rings) blocks of the statistics, in their documented order."""
    colour, rest = stats[:, : 3 * N_RINGS], stats[:, 3 * N_RINGS :]
    names = ("std_log", "max_log", "texture", "bright_share")
    blocks = {n: rest[:, i * N_RINGS : (i + 1) * N_RINGS] for i, n in enumerate(names)}
    return {"colour": colour.reshape(-1, 3, N_RINGS), **blocks}


def test_ring_statistics_of_a_flat_patch() -> None:
    rgb = torch.tensor([60.0, 120.0, 30.0]) / 255
    x = rgb[None, :, None, None].expand(2, 3, 33, 33)
    s = split(RingStatistics(33)(x))
    expected = torch.log1p(rgb * 255)[None, :, None].expand(2, 3, N_RINGS)
    # A ring's mean is a float32 product with its weights: summation order (the CPU's
    # kernels) moves it by ~1e-5, far below a grey level in log space.
    torch.testing.assert_close(s["colour"], expected, rtol=0, atol=1e-4)
    torch.testing.assert_close(s["max_log"], torch.full((2, N_RINGS), float(np.log1p(70.0))))
    torch.testing.assert_close(s["std_log"], torch.full((2, N_RINGS), 1e-3))
    assert s["texture"].abs().max() < 1e-6
    assert (s["bright_share"] > 0.99).all()  # every pixel is as bright as the centre


def test_ring_statistics_of_a_lone_dot() -> None:
    x = torch.zeros(1, 3, 33, 33)
    x[0, :, 16, 16] = 1.0
    s = split(RingStatistics(33)(x))
    assert s["max_log"][0, 0] == pytest.approx(np.log1p(255.0), rel=1e-5)
    assert (s["max_log"][0, 1:] == 0).all()
    assert s["texture"][0, 0] > 0  # the dot's edges lie within 1.5 px
    assert (s["texture"][0, 1:] == 0).all()


def ring_statistics_reference(x: np.ndarray) -> np.ndarray:
    """`RingStatistics` of one (3, S, S) patch, ring by ring from boolean masks."""
    v = x.astype(np.float64) * 255.0
    lum = v.mean(axis=0)
    size = lum.shape[0]
    c = size // 2
    offsets = np.arange(size) - c
    radius = np.hypot(offsets[:, None], offsets[None, :])
    gradient = np.zeros_like(lum)
    gradient[1:, :] += np.abs(np.diff(lum, axis=0))
    gradient[:, 1:] += np.abs(np.diff(lum, axis=1))
    bright = 1.0 / (1.0 + np.exp(-(lum - 0.5 * lum[c - 1 : c + 2, c - 1 : c + 2].mean()) / 4.0))
    blocks: dict[str, list[float]] = {k: [] for k in ("std", "max", "texture", "bright")}
    colour = []
    for inner, outer in itertools.pairwise(RING_EDGES):
        ring = (radius >= inner) & (radius < outer)
        log_lum = np.log1p(lum[ring])
        colour.append(np.log1p(v[:, ring]).mean(axis=1))
        blocks["std"].append(np.sqrt(log_lum.var() + 1e-6))
        blocks["max"].append(log_lum.max())
        blocks["texture"].append(np.log1p(gradient[ring].mean()))
        blocks["bright"].append(bright[ring].mean())
    return np.concatenate([np.array(colour).T.ravel(), *map(np.array, blocks.values())])


@pytest.mark.parametrize("size", [25, 33, 65])
def test_ring_statistics_match_a_ring_by_ring_reference(size: int) -> None:
    rng = np.random.default_rng(size)
    x = rng.integers(0, 256, (4, 3, size, size)) / 255.0
    x[:2] *= 0.05  # dark patches: small logarithms, near-flat rings
    got = RingStatistics(size)(torch.tensor(x, dtype=torch.float32)).numpy()
    expected = np.stack([ring_statistics_reference(patch) for patch in x])
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-5)


def test_rings_need_a_large_enough_patch() -> None:
    with pytest.raises(ValueError, match="too small"):
        RingStatistics(17)


def test_flashnet_shapes_and_calibrated_output() -> None:
    torch.manual_seed(0)
    net = FlashNet(33, widths=(4, 8, 8)).eval()
    x = torch.rand(5, 3, 33, 33)
    logits = net(x)
    assert logits.shape == (5,)
    p = CalibratedFlashNet(net, slope=0.5, intercept=-1.0)(x)
    torch.testing.assert_close(p, torch.sigmoid(logits * 0.5 - 1.0))
