"""Frame ranges of a camera that can be tracked independently, and what each decodes.

Tracking is exactly chunkable (see `pipeline.tracking`): the EWMA background restarts on
a fixed global grid of blocks, each warmed on the frames just before it, so any frame
range equals the whole run. Planning chunks needs only the frame count, the frame rate
and the tracking parameters; it lives here, apart from the tracker, so that the service
can plan a job without loading OpenCV or SciPy.
"""

from __future__ import annotations

import math

from pipeline.params import TrackingParams


def frames_read(start: int, stop: int, fps: float, params: TrackingParams) -> tuple[int, int]:
    """Global frame range ``[first, stop)`` that tracking ``[start, stop)`` decodes.

    ``first`` is where the background model's warm-up begins: the start of the EWMA
    block's warm-up, or ``2L + 2`` frames before ``start`` for the box mean (``L`` for
    the mean, ``L`` more for the noise window measured against it, sampled every other
    frame); and at least ``recurrence_window_s`` before ``start``, the past each
    candidate's spot is looked up in (`pipeline.recurrence`).
    """
    history = math.ceil(params.recurrence_window_s * fps)  # `pipeline.recurrence`
    if params.background == "box":
        first = start - max(2 * box_length(fps, params) + 2, history)
    else:
        block, warmup = block_grid(fps, params)
        first = min((start // block) * block - warmup, start - history)
    return max(0, first), stop


def chunk_ranges(
    n_frames: int, fps: float, params: TrackingParams, chunk_s: float = 60.0
) -> list[tuple[int, int]]:
    """Frame ranges of about `chunk_s` seconds that tile ``[0, n_frames)``.

    Every range is exact whatever its bounds. For the EWMA background, chunks of at
    least half a block are rounded to whole blocks, so each starts on the block grid
    and decodes only the warm-up before it; shorter chunks decode from the warm-up of
    the block they start in (up to ``block_s`` more).

    Parameters
    ----------
    n_frames : int
        Frames in the video.
    fps : float
        Frame rate, frames per second.
    params : TrackingParams
        Background model and its block grid.
    chunk_s : float
        Target chunk length in seconds.

    Returns
    -------
    list of (start, stop)
        Consecutive half-open ranges; empty for an empty video.
    """
    if n_frames < 0:
        raise ValueError(f"n_frames must be non-negative, got {n_frames}")
    if fps <= 0 or chunk_s <= 0:
        raise ValueError(f"fps and chunk_s must be positive, got fps={fps}, chunk_s={chunk_s}")
    step = max(1, round(chunk_s * fps))
    block, _ = block_grid(fps, params)
    if params.background == "ewma" and 2 * step >= block:
        step = max(1, round(step / block)) * block
    return [(a, min(a + step, n_frames)) for a in range(0, n_frames, step)]


def block_grid(fps: float, params: TrackingParams) -> tuple[int, int]:
    """EWMA block length and warm-up length, in frames."""
    block = max(1, round(params.block_s * fps))
    warmup = min(block, round(params.warmup_tau * params.tau_s * fps))
    return block, warmup


def box_length(fps: float, params: TrackingParams) -> int:
    return max(1, round(params.tau_s * fps))
