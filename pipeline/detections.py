"""Per-camera flash detections: a columnar table with CSV and NPZ round trips.

One row per candidate blob in one frame of one camera. Positions follow the pixel
convention of `pipeline.geometry` (``x = u`` column, ``y = v`` row, pixel centres at
integers); frames are 0-based and global across a camera's chapters.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import ClassVar, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Columns written to ``flashes_cam*.csv``, in order (CONTRACT: starts with frame,x,y).
CSV_COLUMNS = ("frame", "x", "y", "area", "peak", "flash_probability", "snr")


@dataclass(frozen=True)
class Detections:
    """Candidate flashes of one camera, one row per blob per frame.

    Attributes
    ----------
    frame : int64
        Global 0-based frame index.
    x, y : float64
        Position of the spot in pixels (``x = u``): the sub-pixel peak of the matched
        filter's response (`pipeline.blobs.subpixel_peak`), refined along the light
        curve once the candidates are merged (`pipeline.refine`).
    area : int32
        Number of pixels in the connected component.
    peak : float32
        Largest foreground value in the blob (0–255 scale of the luminance plane).
    peak_x, peak_y : int32
        Pixel of the largest luminance in the blob: the centre of its patch.
    flash_probability : float32
        Classifier output in [0, 1]; NaN where no classifier was run.
    snr : float32
        Largest matched-filter response of the blob in units of the noise σ
        (`pipeline.tracking`); NaN for detections made elsewhere.
    recurrence : float32
        Share of the frames 0.5–3 s before in which the spot was as bright
        (`pipeline.recurrence`); NaN where not measured.
    trough : float32
        Lowest matched-filter response around the peak over the peak's own
        (`pipeline.blobs.trough`): about 0 for a light that appeared from nothing, well
        below 0 beside a light that moved or a swaying edge; NaN where not measured.
    hollow : float32
        How much darker than 0.1–0.4 s before the darkest spot around the peak has
        become, over the peak's response (`pipeline.hollow`): about 0 for a flash, down
        to −1 beside a light that moved; NaN where not measured.
    """

    frame: np.ndarray
    x: np.ndarray
    y: np.ndarray
    area: np.ndarray
    peak: np.ndarray
    peak_x: np.ndarray
    peak_y: np.ndarray
    flash_probability: np.ndarray
    snr: np.ndarray
    recurrence: np.ndarray
    trough: np.ndarray
    hollow: np.ndarray

    _DTYPES: ClassVar[dict[str, type]] = {
        "frame": np.int64,
        "x": np.float64,
        "y": np.float64,
        "area": np.int32,
        "peak": np.float32,
        "peak_x": np.int32,
        "peak_y": np.int32,
        "flash_probability": np.float32,
        "snr": np.float32,
        "recurrence": np.float32,
        "trough": np.float32,
        "hollow": np.float32,
    }

    def __post_init__(self) -> None:
        n = None
        for f in fields(self):
            col: np.ndarray = np.ascontiguousarray(
                getattr(self, f.name), dtype=self._DTYPES[f.name]
            )
            if col.ndim != 1:
                raise ValueError(f"column {f.name!r} must be one-dimensional")
            if n is not None and len(col) != n:
                raise ValueError("all detection columns must have the same length")
            n = len(col)
            object.__setattr__(self, f.name, col)

    @classmethod
    def from_columns(
        cls,
        frame: ArrayLike,
        x: ArrayLike,
        y: ArrayLike,
        *,
        area: ArrayLike | None = None,
        peak: ArrayLike | None = None,
        peak_x: ArrayLike | None = None,
        peak_y: ArrayLike | None = None,
        flash_probability: ArrayLike | None = None,
        snr: ArrayLike | None = None,
        recurrence: ArrayLike | None = None,
        trough: ArrayLike | None = None,
        hollow: ArrayLike | None = None,
    ) -> Self:
        """Build a table from the required columns; optional ones get neutral defaults.

        Missing ``peak_x``/``peak_y`` default to the rounded centroid, ``area`` to 1,
        ``peak``, ``flash_probability``, ``snr``, ``recurrence``, ``trough`` and ``hollow`` to
        NaN.
        """
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        n = len(x)
        return cls(
            frame=np.asarray(frame),
            x=x,
            y=y,
            area=np.ones(n) if area is None else np.asarray(area),
            peak=np.full(n, np.nan) if peak is None else np.asarray(peak),
            peak_x=np.rint(x) if peak_x is None else np.asarray(peak_x),
            peak_y=np.rint(y) if peak_y is None else np.asarray(peak_y),
            flash_probability=(
                np.full(n, np.nan) if flash_probability is None else np.asarray(flash_probability)
            ),
            snr=np.full(n, np.nan) if snr is None else np.asarray(snr),
            recurrence=np.full(n, np.nan) if recurrence is None else np.asarray(recurrence),
            trough=np.full(n, np.nan) if trough is None else np.asarray(trough),
            hollow=np.full(n, np.nan) if hollow is None else np.asarray(hollow),
        )

    @classmethod
    def empty(cls) -> Self:
        return cls.from_columns(np.zeros(0), np.zeros(0), np.zeros(0))

    @classmethod
    def concat(cls, parts: Iterable[Detections]) -> Self:
        parts = list(parts)
        if not parts:
            return cls.empty()
        return cls(
            **{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)}
        )

    def __len__(self) -> int:
        return len(self.frame)

    def select(self, index: NDArray[np.bool_] | NDArray[np.integer]) -> Self:
        """Rows picked by a boolean mask or an integer index array."""
        return type(self)(**{f.name: getattr(self, f.name)[index] for f in fields(self)})

    def sorted(self) -> Self:
        """Rows ordered by frame, then row, then column (a canonical order)."""
        return self.select(np.lexsort((self.x, self.y, self.frame)))

    def with_probability(self, flash_probability: ArrayLike) -> Self:
        return self._replaced(flash_probability=np.asarray(flash_probability))

    def with_positions(self, x: ArrayLike, y: ArrayLike) -> Self:
        """The same rows at other positions (`pipeline.refine`)."""
        return self._replaced(x=np.asarray(x), y=np.asarray(y))

    def _replaced(self, **columns: NDArray) -> Self:
        return type(self)(**(self.columns() | columns))

    def counts_per_frame(self, n_frames: int) -> NDArray[np.int64]:
        """Number of detections in each frame ``0 .. n_frames-1``: the series N(k)."""
        inside = (self.frame >= 0) & (self.frame < n_frames)
        return np.bincount(self.frame[inside], minlength=n_frames).astype(np.int64)

    def columns(self) -> dict[str, NDArray]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    # -- files -----------------------------------------------------------------

    def to_npz(self, path: str | Path, *, spots_only: bool = False) -> None:
        """Lossless compact file for passing detections between stages.

        With `spots_only`, only the frame, the position (float32: 1/2000 px at 8K) and
        the SNR (float32), for many rows whose other columns are neutral (faint peaks):
        a third of the size.
        """
        if not spots_only:
            np.savez_compressed(path, allow_pickle=False, **self.columns())
            return
        np.savez_compressed(
            path,
            allow_pickle=False,
            frame=self.frame.astype(np.int32),
            x=self.x.astype(np.float32),
            y=self.y.astype(np.float32),
            snr=self.snr,
        )

    @classmethod
    def from_npz(cls, path: str | Path) -> Self:
        """Read `to_npz`'s file; absent columns (spots only, or files written before
        ``snr`` and ``recurrence`` existed) get `from_columns`' neutral defaults."""
        with np.load(path) as data:
            columns = {f.name: data[f.name] for f in fields(cls) if f.name in data}
        return cls.from_columns(**columns)

    def to_csv(self, path: str | Path) -> None:
        """Write ``frame,x,y,area,peak,flash_probability,snr`` (the CONTRACT header)."""
        write_csv(
            path,
            {
                "frame": self.frame,
                "x": self.x,
                "y": self.y,
                "area": self.area,
                "peak": self.peak,
                "flash_probability": self.flash_probability,
                "snr": self.snr,
            },
            formats={
                "x": "%.4f",
                "y": "%.4f",
                "peak": "%.2f",
                "flash_probability": "%.5f",
                "snr": "%.2f",
            },
        )

    @classmethod
    def from_csv(cls, path: str | Path) -> Self:
        """Read a detections CSV whose header contains at least ``frame,x,y``.

        Extra columns are ignored; ``area``, ``peak``, ``flash_probability`` and ``snr``
        are used when present. Raises ``ValueError`` naming the file on a malformed table.
        """
        table = read_csv(path, required=("frame", "x", "y"))
        frame = table["frame"]
        if len(frame) and not np.all(np.isfinite(frame) & (frame == np.round(frame))):
            raise ValueError(f"{path}: column 'frame' must hold integers")
        if len(frame) and np.any(frame < 0):
            raise ValueError(f"{path}: column 'frame' must be non-negative")
        return cls.from_columns(
            frame.astype(np.int64),
            table["x"],
            table["y"],
            area=table.get("area"),
            peak=table.get("peak"),
            flash_probability=table.get("flash_probability"),
            snr=table.get("snr"),
        )


def write_csv(
    path: str | Path,
    columns: dict[str, ArrayLike],
    formats: dict[str, str] | None = None,
) -> None:
    """Write equal-length columns as a CSV with a header row.

    Integer columns are written as integers, floats with ``formats[name]`` (default
    ``%.6g``); NaN is written as an empty field.
    """
    formats = formats or {}
    names = list(columns)
    arrays = [np.asarray(columns[name]) for name in names]
    lengths = {len(a) for a in arrays}
    if len(lengths) > 1:
        raise ValueError("all CSV columns must have the same length")
    text_cols = [
        _format_column(a, formats.get(name)) for name, a in zip(names, arrays, strict=True)
    ]
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(names) + "\n")
        if text_cols and len(text_cols[0]):
            rows = np.char.add(text_cols[0], "")
            for col in text_cols[1:]:
                rows = np.char.add(np.char.add(rows, ","), col)
            fh.write("\n".join(rows.tolist()))
            fh.write("\n")


def _format_column(values: NDArray, fmt: str | None) -> NDArray[np.str_]:
    if values.dtype.kind == "U":  # text (e.g. ISO 8601 times), written as it is
        return values
    if values.dtype.kind in "iub":
        return values.astype(np.int64).astype(str)
    fmt = fmt or "%.6g"
    out = np.char.mod(fmt, values.astype(np.float64))
    return np.where(np.isnan(values.astype(np.float64)), "", out)


def read_csv(
    path: str | Path, required: Sequence[str] = (), text: Sequence[str] = ()
) -> dict[str, NDArray]:
    """Read a numeric CSV with a header row into float64 columns (empty field = NaN).

    Columns named in `text` (if present) are returned as strings, as written.

    Raises
    ------
    ValueError
        If the file is empty, a required column is missing, or a value is not numeric;
        the message names the file (and the line for bad values).
    """
    path = Path(path)
    with open(path, encoding="utf-8") as fh:
        header = fh.readline().strip()
        if not header:
            raise ValueError(f"{path}: empty file, expected a header row")
        names = [h.strip() for h in header.split(",")]
        missing = [c for c in required if c not in names]
        if missing:
            raise ValueError(
                f"{path}: missing column(s) {', '.join(missing)}; header is {header!r}"
            )
        lines = [line for line in fh.read().splitlines() if line.strip()]
    numeric = [j for j, name in enumerate(names) if name not in text]
    data = np.full((len(lines), len(names)), np.nan)
    strings: list[list[str]] = []
    for i, line in enumerate(lines):
        cells = line.split(",")
        if len(cells) != len(names):
            raise ValueError(f"{path}: line {i + 2} has {len(cells)} fields, expected {len(names)}")
        if len(numeric) < len(names):
            strings.append(cells)
        try:
            data[i, numeric] = [float(cells[j]) if cells[j].strip() else np.nan for j in numeric]
        except ValueError as exc:
            raise ValueError(f"{path}: line {i + 2}: {exc}") from None
    columns: dict[str, NDArray] = {}
    for j, name in enumerate(names):
        if name in text:
            columns[name] = np.array([row[j] for row in strings], dtype=str)
        else:
            columns[name] = data[:, j]
    return columns
