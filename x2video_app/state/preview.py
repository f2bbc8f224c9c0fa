"""The formula's preview of a render (tier 0, albedo x irradiance): shown at once when Render is pressed,
replaced frame by frame as the network's frames arrive. Qt-free; the controller runs `preview_frames` in
a generator worker beside the render worker, so the network does not wait for it."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Iterator, Sequence

import numpy as np


@dataclass
class PreviewReady:
    """Formula frames of the shot (linear RGB float32 (H, W, 3) each), standing in until the render's own
    frames arrive. An editor event, not a Renderer event: a render's `FramesReady` always wins over it."""

    frames: dict[int, np.ndarray]
    seconds: float  # wall time spent making them


def preview_order(num_frames: int, first: int | None = None, skip: Sequence[int] = ()) -> list[int]:
    """Frames in the order the preview makes them: `first` (the frame on screen), then coarse to fine, as
    the timeline fills best (`x2video.tiers.base.coarse_to_fine`), without `skip`."""
    from x2video.tiers.base import coarse_to_fine

    done = set(skip)
    order = [] if first is None or first in done else [first]
    done.update(order)
    return order + [t for t in coarse_to_fine(0, num_frames) if t not in done]


def preview_frame(conditioning) -> np.ndarray:
    """One frame of the preview from its (edited) `FrameConditioning`: exactly the formula tier's frame."""
    from x2video.formula import formula_frame

    return np.asarray(formula_frame(conditioning), np.float32)


def preview_frames(shot: Any, edits: Any, frames: Sequence[int], batch: int = 4) -> Iterator[PreviewReady]:
    """Yield the formula's frames of `frames` (in that order) under `edits`, the first alone, then `batch`
    at a time; a generator, so a worker can stop it between yields."""
    from x2video.conditioning.edited import apply_edits

    frames = list(frames)
    i = 0
    while i < len(frames):
        n = 1 if i == 0 else batch
        t0 = time.perf_counter()
        out = {t: preview_frame(apply_edits(shot, edits, t)) for t in frames[i:i + n]}
        i += n
        yield PreviewReady(frames=out, seconds=time.perf_counter() - t0)
