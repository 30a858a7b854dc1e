"""Square RGB patches around blobs, for the flash classifier.

Patch geometry (both functions)
-------------------------------
A patch of ``size`` pixels is centred on the integer pixel ``(cx, cy)`` (column,
row), which lands at index ``size // 2`` of both patch axes. For an even ``size`` the
extra pixel is on the top/left: rows ``cy - size//2 .. cy + size//2 - 1``. Columns
wrap around the 360° seam (column ``-1`` is ``W - 1``); rows beyond the poles are
clamped, replicating the first or last row.

Colour
------
`extract_patches` converts only the gathered pixels from the frame's YUV planes to
RGB, with the matrix and range the stream declares (`pipeline.video.YuvEncoding`;
untagged HD streams are taken as BT.709, SD as BT.601, limited range unless the pixel
format is a full-range ``yuvj`` one). Chroma is sampled at the subsampled position
covering each pixel (nearest neighbour, no chroma-siting interpolation).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pipeline.video import Frame, YuvEncoding

_KR_KB = {"bt601": (0.299, 0.114), "bt709": (0.2126, 0.0722), "bt2020": (0.2627, 0.0593)}


def extract_patches(frame: Frame, cx: ArrayLike, cy: ArrayLike, size: int) -> NDArray[np.uint8]:
    """RGB patches of a decoded frame, centred on integer pixels.

    Parameters
    ----------
    frame : Frame
        Decoded frame (planar YUV).
    cx, cy : array_like of int, shape (N,)
        Patch centres: column ``u`` (any integer; wraps) and row ``v`` (clamped into
        the frame), typically the blobs' brightest pixels.
    size : int
        Patch side in pixels.

    Returns
    -------
    ndarray of uint8, shape (N, size, size, 3)
        RGB patches; the centre pixel is at ``[size // 2, size // 2]``.
    """
    rows, cols = _patch_grid(cx, cy, size, frame.width, frame.height)
    sub_y = frame.height // frame.u.shape[0]
    sub_x = frame.width // frame.u.shape[1]
    chroma_rows, chroma_cols = rows // sub_y, cols // sub_x
    luma = _gather(frame.y, rows, cols)
    cb = _gather(frame.u, chroma_rows, chroma_cols)
    cr = _gather(frame.v, chroma_rows, chroma_cols)
    return yuv_to_rgb(luma, cb, cr, frame.encoding)


def _gather(
    plane: NDArray[np.uint8], rows: NDArray[np.intp], cols: NDArray[np.intp]
) -> NDArray[np.uint8]:
    """``plane[rows, cols]`` (broadcast) through flat offsets into the plane's buffer.

    A 2-D gather costs four times a flat `take` on a 4K frame; the plane may be a
    strided view of the decoder's buffer, so the offsets follow its strides rather than
    a copy.
    """
    if min(plane.strides) <= 0:
        plane = np.ascontiguousarray(plane)
    step_row, step_col = (stride // plane.itemsize for stride in plane.strides)
    extent = (plane.shape[0] - 1) * step_row + (plane.shape[1] - 1) * step_col + 1
    buffer = np.lib.stride_tricks.as_strided(plane, (extent,), (plane.itemsize,))
    return np.asarray(buffer.take(rows * step_row + cols * step_col))


def extract_patches_from_image(
    image: NDArray[np.generic], cx: ArrayLike, cy: ArrayLike, size: int
) -> NDArray[np.generic]:
    """Patches of an image array, with the same centring, wrap and clamp rules.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        Equirectangular image of any dtype (e.g. RGB from a PNG).
    cx, cy : array_like of int, shape (N,)
        Patch centres: column (wraps) and row (clamped).
    size : int
        Patch side in pixels.

    Returns
    -------
    ndarray, shape (N, size, size) or (N, size, size, C)
        Patches of the image's dtype.
    """
    if image.ndim not in (2, 3):
        raise ValueError(f"image must be (H, W) or (H, W, C), got shape {image.shape}")
    rows, cols = _patch_grid(cx, cy, size, image.shape[1], image.shape[0])
    return image[rows, cols]


def yuv_to_rgb(
    y: NDArray[np.uint8], u: NDArray[np.uint8], v: NDArray[np.uint8], encoding: YuvEncoding
) -> NDArray[np.uint8]:
    """Convert YUV samples (any equal shape) to RGB, appending an axis of 3.

    Parameters
    ----------
    y, u, v : ndarray of uint8
        Luma, Cb and Cr samples of the same pixels.
    encoding : YuvEncoding
        Matrix (BT.601/709/2020) and range (full or limited) of the samples.

    Returns
    -------
    ndarray of uint8, shape ``y.shape + (3,)``
        RGB, rounded and clipped to 0–255.
    """
    kr, kb = _KR_KB[encoding.matrix]
    kg = 1.0 - kr - kb
    if encoding.full_range:
        y_off, y_scale, c_scale = 0.0, 1.0, 1.0
    else:
        y_off, y_scale, c_scale = 16.0, 255.0 / 219.0, 255.0 / 224.0
    luma = (y.astype(np.float32) - y_off) * y_scale
    pb = (u.astype(np.float32) - 128.0) * c_scale
    pr = (v.astype(np.float32) - 128.0) * c_scale
    r = luma + 2.0 * (1.0 - kr) * pr
    b = luma + 2.0 * (1.0 - kb) * pb
    g = (luma - kr * r - kb * b) / kg
    rgb = np.stack([r, g, b], axis=-1)
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)


def _patch_grid(
    cx: ArrayLike, cy: ArrayLike, size: int, width: int, height: int
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Row and column index arrays of shape (N, size, 1) and (N, 1, size)."""
    if size < 1:
        raise ValueError(f"patch size must be a positive number of pixels, got {size}")
    cx_arr = np.asarray(cx)
    cy_arr = np.asarray(cy)
    if cx_arr.ndim != 1 or cx_arr.shape != cy_arr.shape:
        raise ValueError(
            f"patch centres cx, cy must be 1-D arrays of equal length, "
            f"got shapes {cx_arr.shape} and {cy_arr.shape}"
        )
    if cx_arr.dtype.kind not in "iu" or cy_arr.dtype.kind not in "iu":
        raise ValueError(
            f"patch centres must be integer pixels, got dtypes {cx_arr.dtype} and {cy_arr.dtype}"
        )
    offsets = np.arange(size, dtype=np.intp) - size // 2
    rows = np.clip(cy_arr.astype(np.intp)[:, None] + offsets, 0, height - 1)
    cols = np.mod(cx_arr.astype(np.intp)[:, None] + offsets, width)
    return rows[:, :, None], cols[:, None, :]
