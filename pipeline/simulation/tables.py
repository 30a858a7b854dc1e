"""Ground-truth tables: columnar, one row per flash per frame (or per artifact per frame)."""

from __future__ import annotations

import functools
import io
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Self

import numpy as np
from numpy.typing import NDArray


class Table:
    """Frozen dataclass of equal-length one-dimensional columns with a CSV round trip.

    Subclasses are ``@dataclass(frozen=True)`` and list each column's dtype in
    ``DTYPES`` (same order as the fields) and printf formats of float columns in
    ``FORMATS``. Columns added after files were first written are ``OPTIONAL``: they
    come last, default to ``None`` (filled with NaN) and may be missing from a file.
    """

    DTYPES: ClassVar[dict[str, Any]]
    FORMATS: ClassVar[dict[str, str]] = {}
    OPTIONAL: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        lengths = set()
        absent = [name for name in self.OPTIONAL if getattr(self, name) is None]
        if absent:
            required = next(name for name in self.DTYPES if name not in absent)
            n = len(np.atleast_1d(getattr(self, required)))
            for name in absent:
                object.__setattr__(self, name, np.full(n, np.nan))
        for name, dtype in self.DTYPES.items():
            col = np.ascontiguousarray(getattr(self, name), dtype=dtype)
            if col.ndim != 1:
                raise ValueError(f"{type(self).__name__}.{name} must be one-dimensional")
            lengths.add(len(col))
            object.__setattr__(self, name, col)
        if len(lengths) > 1:
            raise ValueError(f"{type(self).__name__} columns differ in length: {sorted(lengths)}")

    def __len__(self) -> int:
        return len(getattr(self, next(iter(self.DTYPES))))

    def columns(self) -> dict[str, NDArray]:
        return {name: getattr(self, name) for name in self.DTYPES}

    def select(self, index: NDArray[np.bool_] | NDArray[np.integer]) -> Self:
        """Rows picked by a boolean mask or an integer index array."""
        return type(self)(**{name: col[index] for name, col in self.columns().items()})

    @classmethod
    def concat(cls, parts: Iterable[Self]) -> Self:
        parts = list(parts)
        return cls(
            **{
                name: np.concatenate([getattr(p, name) for p in parts])
                if parts
                else np.zeros(0, dtype)
                for name, dtype in cls.DTYPES.items()
            }
        )

    def to_csv(self, path: str | Path) -> None:
        """Write a CSV with a header row; booleans as 0/1."""
        text = [_format_column(col, self.FORMATS.get(name)) for name, col in self.columns().items()]
        rows = functools.reduce(lambda a, b: np.char.add(np.char.add(a, ","), b), text)
        with open(path, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(",".join(self.DTYPES) + "\n")
            if len(self):
                fh.write("\n".join(rows.tolist()) + "\n")

    @classmethod
    def from_csv(cls, path: str | Path) -> Self:
        """Read a CSV written by `to_csv`.

        Files written before the ``OPTIONAL`` columns existed lack them: they read as
        NaN.

        Raises
        ------
        ValueError
            If the header does not list this table's columns (the optional ones may
            be missing at its end) or a value does not parse; the message names the
            file and the column.
        """
        path = Path(path)
        with open(path, encoding="utf-8") as fh:
            header = fh.readline().strip().split(",")
            body = fh.read()
        names = list(cls.DTYPES)
        missing = names[len(header) :]
        if header != names[: len(header)] or not set(missing) <= set(cls.OPTIONAL):
            raise ValueError(f"{path}: header {header} differs from {names}")
        text = np.zeros((0, len(header)), dtype=str)
        if body.strip():
            try:
                text = np.loadtxt(io.StringIO(body), delimiter=",", dtype=str, ndmin=2)
            except ValueError as exc:
                raise ValueError(f"{path}: {exc}") from None
        if text.shape[1] != len(header):
            raise ValueError(f"{path}: every row must have {len(header)} fields")
        columns: dict[str, Any] = dict.fromkeys(missing)
        for i, (name, dtype) in enumerate(list(cls.DTYPES.items())[: len(header)]):
            try:
                columns[name] = _parse_column(text[:, i], dtype)
            except ValueError as exc:
                raise ValueError(f"{path}: column {name!r}: {exc}") from None
        return cls(**columns)


def _format_column(values: NDArray, fmt: str | None) -> NDArray[np.str_]:
    if values.dtype.kind in "iub":
        return values.astype(np.int64).astype(str)
    if values.dtype.kind == "U":
        return values
    return np.char.mod(fmt or "%.6g", values)


def _parse_column(text: NDArray[np.str_], dtype: Any) -> NDArray:
    kind = np.dtype(dtype).kind
    if kind == "U":
        return text.astype(dtype)
    if kind in "iub":
        return text.astype(np.int64).astype(dtype)
    return text.astype(np.float64).astype(dtype)


@dataclass(frozen=True)
class FlashTruth(Table):
    """True flashes, one row per flash per frame (``truth_flashes.csv``).

    Attributes
    ----------
    flash_id : int64
        One flash = one continuous emission (3–6 frames in synthetic scenarios).
    firefly_id : int64
        Which firefly emitted it; ``-1`` where unknown (``real3d``).
    frame1, frame2 : int64
        Frame in camera 1 and in camera 2 (``frame2 = frame1 + delay_frames``); a
        frame outside a camera's recording is still listed (then ``visible = False``).
    x, y, z : float64
        Position in metres in camera 1's frame (``z`` up; the ground is at ``z = −h``).
    u1, v1, u2, v2 : float64
        Exact projections in each camera (`pipeline.geometry` convention).
    visible1, visible2 : bool
        Inside that camera's recording and not hidden by vegetation: rendered.
    intensity : float64
        Emitted intensity in this frame relative to a typical flash peak (rise/fall
        profile included).
    peak1, peak2 : float64
        Peak of the rendered spot above the background in each camera, luma 0–255
        scale before saturation (also where not visible): the peak of the continuous
        point-spread, before pixel integration and motion streaking.

    The following columns were added for the detection evaluation (issue 7); truth
    files written before lack them (NaN when read):

    range1, range2 : float64
        Distance of the flash from each camera's centre, metres.
    psf1, psf2 : float64
        Point-spread σ in pixels in each camera.
    streak_u1, streak_v1, streak_u2, streak_v2 : float64
        Motion during the exposure, pixels: the spot is integrated from
        ``(u, v) − ½ streak`` to ``(u, v) + ½ streak`` (0 without motion blur).
    whiteness : float64
        Flash colour: 0 yellow-green (`render.FIREFLY_RGB`) … 1 near-white.
    amp1, amp2 : float64
        Drawn peak amplitude: the most any pixel of the flash rises above the
        background, luma 0–255 scale (RGB before encoding; the decoded, limited-range
        Y plane shows 219/255 of it), after pixel integration and streaking, before
        noise, saturation and compression.
    noise1, noise2 : float64
        σ of the sensor noise at the flash's pixel in that frame (read noise, shot
        noise of the background, grain), same scale as ``amp``.
    snr1, snr2 : float64
        Peak signal-to-noise ratio ``amp / noise``.
    snr_mf1, snr_mf2 : float64
        The SNR at the peak of a σ = 1 px Gaussian matched filter against the same
        sensor noise, with the grain's spatial correlation
        (`pipeline.simulation.snr.matched_filter_snr`).
    """

    flash_id: np.ndarray
    firefly_id: np.ndarray
    frame1: np.ndarray
    frame2: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    u1: np.ndarray
    v1: np.ndarray
    visible1: np.ndarray
    u2: np.ndarray
    v2: np.ndarray
    visible2: np.ndarray
    intensity: np.ndarray
    peak1: np.ndarray
    peak2: np.ndarray
    # Optional (newer) columns: None = absent, filled with NaN.
    range1: np.ndarray = None  # type: ignore[assignment]
    range2: np.ndarray = None  # type: ignore[assignment]
    psf1: np.ndarray = None  # type: ignore[assignment]
    psf2: np.ndarray = None  # type: ignore[assignment]
    streak_u1: np.ndarray = None  # type: ignore[assignment]
    streak_v1: np.ndarray = None  # type: ignore[assignment]
    streak_u2: np.ndarray = None  # type: ignore[assignment]
    streak_v2: np.ndarray = None  # type: ignore[assignment]
    whiteness: np.ndarray = None  # type: ignore[assignment]
    amp1: np.ndarray = None  # type: ignore[assignment]
    amp2: np.ndarray = None  # type: ignore[assignment]
    noise1: np.ndarray = None  # type: ignore[assignment]
    noise2: np.ndarray = None  # type: ignore[assignment]
    snr1: np.ndarray = None  # type: ignore[assignment]
    snr2: np.ndarray = None  # type: ignore[assignment]
    snr_mf1: np.ndarray = None  # type: ignore[assignment]
    snr_mf2: np.ndarray = None  # type: ignore[assignment]

    OPTIONAL: ClassVar[tuple[str, ...]] = (
        "range1",
        "range2",
        "psf1",
        "psf2",
        "streak_u1",
        "streak_v1",
        "streak_u2",
        "streak_v2",
        "whiteness",
        "amp1",
        "amp2",
        "noise1",
        "noise2",
        "snr1",
        "snr2",
        "snr_mf1",
        "snr_mf2",
    )
    DTYPES: ClassVar[dict[str, Any]] = {
        "flash_id": np.int64,
        "firefly_id": np.int64,
        "frame1": np.int64,
        "frame2": np.int64,
        "x": np.float64,
        "y": np.float64,
        "z": np.float64,
        "u1": np.float64,
        "v1": np.float64,
        "visible1": np.bool_,
        "u2": np.float64,
        "v2": np.float64,
        "visible2": np.bool_,
        "intensity": np.float64,
        "peak1": np.float64,
        "peak2": np.float64,
        **dict.fromkeys(OPTIONAL, np.float64),
    }
    FORMATS: ClassVar[dict[str, str]] = {
        "x": "%.6f",
        "y": "%.6f",
        "z": "%.6f",
        "u1": "%.5f",
        "v1": "%.5f",
        "u2": "%.5f",
        "v2": "%.5f",
        "intensity": "%.4f",
        "peak1": "%.2f",
        "peak2": "%.2f",
        "range1": "%.4f",
        "range2": "%.4f",
        "psf1": "%.3f",
        "psf2": "%.3f",
        "streak_u1": "%.3f",
        "streak_v1": "%.3f",
        "streak_u2": "%.3f",
        "streak_v2": "%.3f",
        "whiteness": "%.3f",
        "amp1": "%.3f",
        "amp2": "%.3f",
        "noise1": "%.4f",
        "noise2": "%.4f",
        "snr1": "%.3f",
        "snr2": "%.3f",
        "snr_mf1": "%.3f",
        "snr_mf2": "%.3f",
    }

    def position(self) -> NDArray[np.float64]:
        """``(x, y, z)`` rows, shape (n, 3), metres."""
        return np.column_stack([self.x, self.y, self.z])

    def in_camera(self, camera: int) -> tuple[NDArray[np.int64], NDArray, NDArray, NDArray]:
        """``(frame, u, v, visible)`` columns of camera 1 or 2."""
        if camera == 1:
            return self.frame1, self.u1, self.v1, self.visible1
        return self.frame2, self.u2, self.v2, self.visible2

    def camera_column(self, name: str, camera: int) -> NDArray:
        """Column ``name`` + camera number, e.g. ``camera_column("snr", 2)`` is ``snr2``."""
        return getattr(self, f"{name}{camera}")


@dataclass(frozen=True)
class ArtifactTruth(Table):
    """Image positions of non-firefly lights per camera frame (``truth_artifacts.csv``).

    Attributes
    ----------
    camera : int64
        1 or 2.
    frame : int64
        Frame of that camera.
    u, v : float64
        Pixel position of the artifact's centre.
    radius : float64
        Pixels around ``(u, v)`` where candidates belong to this artifact (glow,
        glare, a foliage branch's extent).
    kind : str
        ``lamp``, ``moon``, ``headlight``, ``taillight``, ``flashlight`` or ``foliage``.
    """

    camera: np.ndarray
    frame: np.ndarray
    u: np.ndarray
    v: np.ndarray
    radius: np.ndarray
    kind: np.ndarray

    DTYPES: ClassVar[dict[str, Any]] = {
        "camera": np.int64,
        "frame": np.int64,
        "u": np.float64,
        "v": np.float64,
        "radius": np.float64,
        "kind": "<U16",
    }
    FORMATS: ClassVar[dict[str, str]] = {"u": "%.3f", "v": "%.3f", "radius": "%.2f"}
