"""Patch extraction: centring, seam wrap, pole clamp, YUV → RGB (pipeline.patches)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.patches import extract_patches, extract_patches_from_image, yuv_to_rgb
from pipeline.video import Frame, YuvEncoding, iter_frames, probe_video
from tests.pipeline import video_factory as vf

# A 6 × 8 image whose value names its pixel: 10 · row + column.
IMAGE = (10 * np.arange(6)[:, None] + np.arange(8)[None, :]).astype(np.uint8)


def test_patch_wraps_across_the_seam_and_clamps_at_the_top() -> None:
    patch = extract_patches_from_image(IMAGE, np.array([0]), np.array([0]), 5)[0]
    rows, cols = [0, 0, 0, 1, 2], [6, 7, 0, 1, 2]
    assert np.array_equal(patch, IMAGE[np.ix_(rows, cols)])


def test_patch_wraps_the_other_way_and_clamps_at_the_bottom() -> None:
    patch = extract_patches_from_image(IMAGE, np.array([7]), np.array([5]), 5)[0]
    rows, cols = [3, 4, 5, 5, 5], [5, 6, 7, 0, 1]
    assert np.array_equal(patch, IMAGE[np.ix_(rows, cols)])


def test_columns_outside_the_frame_wrap() -> None:
    left = extract_patches_from_image(IMAGE, np.array([-1, 15]), np.array([2, 2]), 3)
    right = extract_patches_from_image(IMAGE, np.array([7, 7]), np.array([2, 2]), 3)
    assert np.array_equal(left, right)


def test_even_sizes_put_the_extra_pixel_top_left() -> None:
    patch = extract_patches_from_image(IMAGE, np.array([3]), np.array([3]), 4)[0]
    assert np.array_equal(patch, IMAGE[1:5, 1:5])
    assert patch[2, 2] == IMAGE[3, 3]


def test_brightest_pixel_lands_at_the_centre() -> None:
    rng = np.random.default_rng(3)
    image = rng.integers(0, 200, (40, 80, 3), dtype=np.uint8)
    cx = np.array([0, 79, 13, 40, 5])
    cy = np.array([0, 39, 20, 1, 38])
    image[cy, cx] = 255
    for size in (9, 10, 33):
        patches = extract_patches_from_image(image, cx, cy, size)
        assert patches.shape == (5, size, size, 3)
        assert np.all(patches[:, size // 2, size // 2] == 255)


def test_rgb_image_channels_are_kept() -> None:
    rgb = np.stack([IMAGE, IMAGE + 100, IMAGE + 200], axis=-1)
    patch = extract_patches_from_image(rgb, np.array([4]), np.array([2]), 3)[0]
    assert np.array_equal(patch[1, 1], [24, 124, 224])


def test_bad_centres_and_sizes_are_refused() -> None:
    with pytest.raises(ValueError, match="patch size must be a positive number"):
        extract_patches_from_image(IMAGE, np.array([1]), np.array([1]), 0)
    with pytest.raises(ValueError, match="must be integer pixels"):
        extract_patches_from_image(IMAGE, np.array([1.5]), np.array([1.0]), 3)
    with pytest.raises(ValueError, match="equal length"):
        extract_patches_from_image(IMAGE, np.array([1, 2]), np.array([1]), 3)


def test_frame_patches_follow_the_same_geometry() -> None:
    luma = np.repeat(np.repeat(IMAGE, 2, axis=0), 2, axis=1) + 16  # 12 × 16
    chroma = np.full((6, 8), 128, np.uint8)
    frame = Frame(0, luma, chroma, chroma, YuvEncoding("bt601", full_range=True))
    patch = extract_patches(frame, np.array([0]), np.array([0]), 3)[0]
    rows, cols = [0, 0, 1], [15, 0, 1]
    # grey stays grey, and full range keeps the luma value
    assert np.array_equal(patch[..., 0], luma[np.ix_(rows, cols)])
    assert np.array_equal(patch[..., 1], patch[..., 2])


def test_patches_of_strided_planes_equal_those_of_contiguous_ones() -> None:
    # A decoder pads its lines (linesize > width); a flipped plane has negative strides.
    rng = np.random.default_rng(3)
    luma, cb, cr = (rng.integers(0, 256, (h, w), np.uint8) for h, w in [(12, 16), (6, 8), (6, 8)])
    padded = [np.pad(p, ((0, 0), (0, 5)))[:, : p.shape[1]] for p in (luma, cb, cr)]
    flipped = [np.ascontiguousarray(p[::-1, ::-1])[::-1, ::-1] for p in (luma, cb, cr)]
    encoding = YuvEncoding("bt709", full_range=False)
    cx, cy = np.array([0, 15, 7, 3]), np.array([0, 11, 5, 9])
    expected = extract_patches(Frame(0, luma, cb, cr, encoding), cx, cy, 5)
    for planes in (padded, flipped):
        assert not planes[0].flags.c_contiguous
        frame = Frame(0, *planes, encoding)
        np.testing.assert_array_equal(extract_patches(frame, cx, cy, 5), expected)


@pytest.mark.parametrize(
    ("encoding", "yuv", "rgb"),
    [
        # ITU-R BT.601 / BT.709 limited-range codes of the primaries and white/black
        (YuvEncoding("bt601", False), (81, 90, 240), (255, 0, 0)),
        (YuvEncoding("bt601", False), (145, 54, 34), (0, 255, 0)),
        (YuvEncoding("bt709", False), (63, 102, 240), (255, 0, 0)),
        (YuvEncoding("bt709", False), (32, 240, 118), (0, 0, 255)),
        (YuvEncoding("bt709", False), (235, 128, 128), (255, 255, 255)),
        (YuvEncoding("bt709", True), (0, 128, 128), (0, 0, 0)),
    ],
)
def test_yuv_to_rgb_reference_codes(
    encoding: YuvEncoding, yuv: tuple[int, int, int], rgb: tuple[int, int, int]
) -> None:
    y, u, v = (np.array([c], np.uint8) for c in yuv)
    assert np.abs(yuv_to_rgb(y, u, v, encoding)[0].astype(int) - rgb).max() <= 2


@pytest.mark.parametrize(
    ("matrix", "full_range", "size", "tag"),
    [
        ("bt601", False, (640, 320), True),
        ("bt709", False, (640, 320), True),
        ("bt709", True, (640, 320), True),
        ("bt709", False, (1440, 720), False),  # untagged HD is read as BT.709
    ],
)
def test_flat_colour_frame_decodes_to_its_colour(
    tmp_path: Path, matrix: str, full_range: bool, size: tuple[int, int], tag: bool
) -> None:
    width, height = size
    colours = [(200, 40, 60), (30, 170, 90), (70, 60, 220), (128, 128, 128)]
    pictures = [np.full((height, width, 3), c, np.uint8) for c in colours]
    path = vf.write_video(
        tmp_path / "flat.mp4",
        pictures,
        crf=0,
        matrix=matrix,  # type: ignore[arg-type]
        full_range=full_range,
        tag_colour=tag,
    )
    cx = np.array([0, width // 3, width - 1])
    cy = np.array([0, height // 2, height - 1])
    for frame, colour in zip(iter_frames(probe_video([path])), colours, strict=True):
        patches = extract_patches(frame, cx, cy, 7)
        assert np.abs(patches.astype(int) - colour).max() <= 3
