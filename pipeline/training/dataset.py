"""Labelled patch folders: loading, source-recording groups and saving.

A dataset folder holds ``flash/`` and ``background/`` sub-folders of image patches
(.png/.jpg/.jpeg, searched recursively) centred on a blob's brightest pixel. The label
comes from the sub-folder. The *group* of a patch is its source recording, the unit
of every split: file names ``f-<video>-f<frame>x<x>y<y>.png`` / ``b-<video>-...``
(the firefl-eye convention, also written by `save_patch_set`) and
``f-<video>-<index>.png`` (the firefl-eye GoPro set) give ``<video>``; a
file named otherwise belongs to the group of its dataset folder as a whole, because
patches of one recording are strongly correlated and an unknown name gives no safer
split.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Self

import cv2
import numpy as np

from pipeline.classify import center_crop_or_pad

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
CLASS_FOLDERS = {"flash": 1, "background": 0}
_NAME = re.compile(r"^[fb]-(?P<video>.+)-f(?P<frame>\d+)x(?P<x>\d+)y(?P<y>\d+)$")
#: The first firefl-eye GoPro set: ``f-<camera/recording>-<index>`` (e.g. f-gp4941-0001).
_NUMBERED = re.compile(r"^[fb]-(?P<video>[A-Za-z0-9]+)-(?P<index>\d+)$")


@dataclass(frozen=True)
class PatchSet:
    """Labelled patches with their source recording.

    Attributes
    ----------
    images : uint8 (N, S, S, 3)
        RGB patches, brightest pixel at (S // 2, S // 2).
    labels : int8 (N,)
        1 flash, 0 background.
    groups : str (N,)
        Source recording of each patch (the unit of cross-validation splits).
    paths : str (N,)
        Where each patch was read from ("" for generated ones).
    sources : str (N,)
        Dataset folder (or generator) each patch came from: real and simulated data
        are reported separately and balanced across folds.
    """

    images: np.ndarray
    labels: np.ndarray
    groups: np.ndarray
    paths: np.ndarray
    sources: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.images)
        if self.images.ndim != 4 or self.images.shape[3] != 3:
            raise ValueError(f"images must be (N, S, S, 3), got {self.images.shape}")
        columns = (self.labels, self.groups, self.paths, self.sources)
        if any(len(c) != n for c in columns):
            raise ValueError("images, labels, groups, paths and sources must have the same length")

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def size(self) -> int:
        """Patch side in pixels."""
        return int(self.images.shape[1])

    def strata(self) -> np.ndarray:
        """Class × data source of each patch (what grouped folds should balance)."""
        _, source_index = np.unique(self.sources, return_inverse=True)
        return self.labels + 2 * source_index

    def subset(self, index: np.ndarray) -> Self:
        """Rows selected by an integer or boolean index."""
        return type(self)(
            self.images[index],
            self.labels[index],
            self.groups[index],
            self.paths[index],
            self.sources[index],
        )

    def resized(self, size: int) -> Self:
        """The same patches centre-cropped or edge-padded to ``size``."""
        if size == self.size:
            return self
        return type(self)(
            center_crop_or_pad(self.images, size),
            self.labels,
            self.groups,
            self.paths,
            self.sources,
        )

    @classmethod
    def concat(cls, parts: Sequence[PatchSet]) -> Self:
        """Stack patch sets of the same patch size."""
        sizes = {p.size for p in parts}
        if len(sizes) != 1:
            raise ValueError(f"cannot concatenate patch sets of sizes {sorted(sizes)}")
        return cls(
            np.concatenate([p.images for p in parts]),
            np.concatenate([p.labels for p in parts]),
            np.concatenate([p.groups for p in parts]),
            np.concatenate([p.paths for p in parts]),
            np.concatenate([p.sources for p in parts]),
        )


def video_id(path: Path, default: str) -> str:
    """Source recording of a patch from its file name, else ``default``."""
    match = _NAME.match(path.stem) or _NUMBERED.match(path.stem)
    return match["video"] if match else default


def find_images(root: Path) -> list[Path]:
    """Image files under ``root`` (or ``root`` itself), sorted for reproducibility."""
    if root.is_file():
        return [root]
    return sorted(p for p in root.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)


def read_rgb(path: Path) -> np.ndarray | None:
    """An image file as uint8 (H, W, 3) RGB, or None if OpenCV cannot read it."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return None if bgr is None else np.ascontiguousarray(bgr[..., ::-1])


def load_patch_folder(root: str | Path, size: int | None = None) -> PatchSet:
    """Read ``root/flash`` and ``root/background`` into one `PatchSet`.

    Parameters
    ----------
    root : dataset folder.
    size : patch side to bring every image to (centre-crop or edge-pad, see
        `center_crop_or_pad`); None keeps the images' own size, which must then be
        the same square for all.

    Raises
    ------
    ValueError
        If the folder has neither sub-folder, has no images, an image is unreadable,
        or (``size=None``) the images differ in size.
    """
    root = Path(root)
    found = {
        label: find_images(root / name)
        for name, label in CLASS_FOLDERS.items()
        if (root / name).is_dir()
    }
    if not found:
        raise ValueError(f"{root}: expected sub-folders 'flash/' and/or 'background/'")
    files = [(path, label) for label, paths in found.items() for path in paths]
    if not files:
        raise ValueError(f"{root}: no .png/.jpg images under flash/ or background/")
    images = [_read_image(path) for path, _ in files]
    size = size or _common_size(images, root)
    return PatchSet(
        images=np.stack([center_crop_or_pad(im[None], size)[0] for im in images]),
        labels=np.array([label for _, label in files], dtype=np.int8),
        groups=np.array([video_id(path, default=str(root)) for path, _ in files]),
        paths=np.array([str(path) for path, _ in files]),
        sources=np.full(len(files), str(root)),
    )


def load_patch_folders(roots: Iterable[str | Path], size: int) -> PatchSet:
    """`load_patch_folder` over several dataset folders, concatenated."""
    return PatchSet.concat([load_patch_folder(root, size) for root in roots])


def _read_image(path: Path) -> np.ndarray:
    image = read_rgb(path)
    if image is None:
        raise ValueError(f"cannot read image {path}")
    return image


def _common_size(images: Sequence[np.ndarray], root: Path) -> int:
    shapes = {im.shape[:2] for im in images}
    if len(shapes) != 1 or len({*next(iter(shapes))}) != 1:
        raise ValueError(f"{root}: patches differ in size or are not square: {sorted(shapes)}")
    return int(images[0].shape[0])


def save_patch_set(patches: PatchSet, root: str | Path, frames: np.ndarray, xy: np.ndarray) -> None:
    """Write patches as ``root/{flash,background}/{f,b}-<group>-f<frame>x<x>y<y>.png``.

    ``frames`` (N,) and ``xy`` (N, 2) integer pixel positions name each file, so that
    `load_patch_folder` recovers the group of every patch.
    """
    root = Path(root)
    for name in CLASS_FOLDERS:
        (root / name).mkdir(parents=True, exist_ok=True)
    for image, label, group, frame, (x, y) in zip(
        patches.images, patches.labels, patches.groups, frames, xy, strict=True
    ):
        folder, prefix = ("flash", "f") if label else ("background", "b")
        path = root / folder / f"{prefix}-{group}-f{frame:04d}x{x:04d}y{y:04d}.png"
        cv2.imwrite(str(path), image[..., ::-1])


def folder_manifest(root: str | Path) -> dict[str, object]:
    """Identity of a data folder for a model card: per-class counts, a SHA-256 over
    the sorted (relative path, file hash) pairs, and any generator manifest
    (``simulated.json`` / ``synthetic.json``) found in it."""
    import hashlib
    import json

    root = Path(root)
    digest = hashlib.sha256()
    counts = {}
    for name in CLASS_FOLDERS:
        files = find_images(root / name) if (root / name).is_dir() else []
        counts[name] = len(files)
        for path in files:
            digest.update(str(path.relative_to(root)).encode())
            digest.update(hashlib.sha256(path.read_bytes()).digest())
    out: dict[str, object] = {"counts": counts, "sha256": digest.hexdigest()}
    for generator in ("simulated.json", "synthetic.json"):
        if (root / generator).is_file():
            out["generator"] = json.loads((root / generator).read_text())
    return out
