from dataclasses import replace

import numpy as np
import torch

from pipeline.training.augment import NO_AUGMENT, AugmentConfig, augment


def batch() -> torch.Tensor:
    return torch.rand(64, 3, 9, 9, generator=torch.Generator().manual_seed(0))


def test_no_augment_is_identity() -> None:
    x = batch()
    assert torch.equal(augment(x, NO_AUGMENT, torch.Generator()), x)


def test_dihedral_keeps_pixels_and_centre() -> None:
    x = batch()
    config = AugmentConfig(brightness=0, colour=0, blur=0, shift=0, noise=0, streak=0, saturation=0)
    y = augment(x, config, torch.Generator().manual_seed(1))
    assert torch.equal(y[:, :, 4, 4], x[:, :, 4, 4])
    for a, b in zip(x, y, strict=True):
        assert torch.equal(a.flatten().sort().values, b.flatten().sort().values)
    assert not torch.equal(x, y)  # some of 64 patches were flipped


def test_output_stays_in_range_and_is_reproducible() -> None:
    x = batch()
    a = augment(x, AugmentConfig(), torch.Generator().manual_seed(5))
    b = augment(x, AugmentConfig(), torch.Generator().manual_seed(5))
    assert torch.equal(a, b)
    assert a.min() >= 0 and a.max() <= 1


def test_shift_moves_by_at_most_one_pixel() -> None:
    x = torch.zeros(200, 3, 9, 9)
    x[:, :, 4, 4] = 1.0
    config = replace(NO_AUGMENT, shift=1.0)
    y = augment(x, config, torch.Generator().manual_seed(2))
    where = torch.nonzero(y[:, 0] == 1.0)[:, 1:] - 4
    assert len(where) == 200
    assert where.abs().max() == 1
    assert np.unique(where.numpy(), axis=0).shape[0] == 9  # all 3x3 offsets occur


def test_streak_draws_a_line_at_the_former_peak_brightness() -> None:
    x = torch.zeros(100, 3, 9, 9)
    x[:, :, 4, 4] = 0.2
    y = augment(x, replace(NO_AUGMENT, streak=1.0), torch.Generator().manual_seed(3))
    lit = y[:, 0] > 0
    assert (lit.sum(dim=(1, 2)) == 5).all()
    # 5 px share the point: restoring its peak needs gain 5, capped at 4 -> 0.2 * 4 / 5
    torch.testing.assert_close(y[:, 0].amax(dim=(1, 2)), torch.full((100,), 0.16))
    rows = lit.any(dim=2).sum(dim=1)
    assert set(rows.tolist()) == {1, 5}  # horizontal and diagonal streaks both occur


def test_saturation_keeps_grey_and_mixes_colour_towards_it() -> None:
    x = batch()
    config = replace(NO_AUGMENT, saturation=0.8)
    y = augment(x, config, torch.Generator().manual_seed(2))
    # the grey level is kept (up to clipping at 0 and 1)
    assert (y.mean(dim=1) - x.mean(dim=1)).abs().mean() < 0.02
    spread_x = (x - x.mean(dim=1, keepdim=True)).abs().sum(dim=(1, 2, 3))
    spread_y = (y - y.mean(dim=1, keepdim=True)).abs().sum(dim=(1, 2, 3))
    assert (spread_y < spread_x * 0.9).any() and (spread_y > spread_x * 1.05).any()
