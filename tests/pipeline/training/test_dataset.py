from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.training.dataset import (
    PatchSet,
    load_patch_folder,
    load_patch_folders,
    video_id,
)
from tests.pipeline.training.conftest import SIZE, synthetic_patches


@pytest.mark.parametrize(
    ("name", "video"),
    [
        ("f-4607rs1203-f0009x0039y1025.png", "4607rs1203"),
        ("b-4625rs1834-f0120x0001y0002.png", "4625rs1834"),
        ("f-night-2-cam1-f0001x0002y0003.png", "night-2-cam1"),
        ("f-gp4941-0012.png", "gp4941"),
        ("b-gp4941-0001.png", "gp4941"),
        ("patch_0001.png", "DEFAULT"),
        ("f-4607rs1203.png", "DEFAULT"),
    ],
)
def test_video_id_from_file_name(name: str, video: str) -> None:
    assert video_id(Path(name), default="DEFAULT") == video


def test_save_and_load_round_trip(patch_folder: Path) -> None:
    expected = synthetic_patches()
    loaded = load_patch_folder(patch_folder)
    assert loaded.size == SIZE
    assert len(loaded) == len(expected)
    # files are sorted by folder then name: match rows by (group, label) counts and pixels
    for label in (0, 1):
        got = loaded.images[loaded.labels == label]
        want = expected.images[expected.labels == label]
        assert {im.tobytes() for im in got} == {im.tobytes() for im in want}
    assert sorted(set(loaded.groups)) == ["vid0", "vid1", "vid2", "vid3"]
    assert set(loaded.sources) == {str(patch_folder)}


def test_load_resizes_about_the_centre(patch_folder: Path) -> None:
    native = load_patch_folder(patch_folder)
    small = load_patch_folder(patch_folder, 17)
    np.testing.assert_array_equal(small.images, native.images[:, 8:25, 8:25])
    np.testing.assert_array_equal(native.resized(17).images, small.images)


def test_other_names_form_one_group_per_folder(tmp_path: Path) -> None:
    for i, label in enumerate(["flash", "flash", "background"]):
        (tmp_path / label).mkdir(exist_ok=True)
        cv2.imwrite(str(tmp_path / label / f"img{i}.png"), np.full((9, 9, 3), i, np.uint8))
    patches = load_patch_folder(tmp_path)
    np.testing.assert_array_equal(patches.labels, [1, 1, 0])
    assert set(patches.groups) == {str(tmp_path)}


def test_unreadable_image_is_named(patch_folder: Path) -> None:
    bad = patch_folder / "flash" / "f-vid0-f9999x0000y0000.png"
    bad.write_bytes(b"garbage")
    with pytest.raises(ValueError, match=str(bad)):
        load_patch_folder(patch_folder)


def test_mixed_sizes_need_an_explicit_size(tmp_path: Path) -> None:
    (tmp_path / "flash").mkdir()
    cv2.imwrite(str(tmp_path / "flash" / "a.png"), np.zeros((9, 9, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "flash" / "b.png"), np.zeros((11, 11, 3), np.uint8))
    with pytest.raises(ValueError, match="differ in size"):
        load_patch_folder(tmp_path)
    assert load_patch_folder(tmp_path, 9).size == 9


def test_folder_without_class_folders_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="flash/"):
        load_patch_folder(tmp_path)


def test_concat_and_strata(patch_folder: Path, tmp_path: Path) -> None:
    a = load_patch_folder(patch_folder)
    b = PatchSet(a.images, a.labels, a.groups, a.paths, np.full(len(a), "zz"))
    both = PatchSet.concat([a, b])
    assert len(both) == 2 * len(a)
    strata = both.strata()
    assert set(strata[: len(a)]) == {0, 1}
    assert set(strata[len(a) :]) == {2, 3}
    with pytest.raises(ValueError, match="sizes"):
        PatchSet.concat([a, a.resized(9)])
    assert len(load_patch_folders([patch_folder, patch_folder], 9)) == 2 * len(a)
