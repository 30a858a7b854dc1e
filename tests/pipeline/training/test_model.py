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
    torch.testing.assert_close(s["colour"], expected)
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
