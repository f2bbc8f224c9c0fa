"""`formula_frames`: the no-network render (`RenderSettings.quality == "formula"`), as the Renderer's events.

Tier 0 (`x2video.sampling.tiers.formula_frame`): albedo x irradiance of each frame's (edited)
channels, zero inside A|M|R regions. It is exact for diffuse light, needs no weights, works at any
frame size, and emits the same events as `Renderer.render`, so a `FrameSink` or the editor takes
its frames unchanged (one window per frame, level 1).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from x2video.sampling.events import (
    CancelToken,
    EventCallback,
    FramesReady,
    RenderCancelled,
    RenderFailed,
    RenderFinished,
    RenderStarted,
    StepDone,
    WindowStarted,
)
from x2video.sampling.settings import RenderSettings
from x2video.shot import Shot


def formula_frames(
    shot: Shot,
    edits: Any,
    settings: RenderSettings,
    on_event: EventCallback | None = None,
    cancel: CancelToken | None = None,
    *,
    base_dir: str | Path | None = None,
    reason: str = "forced by the user",
) -> None:
    """Render `settings.frames` (default all) of `shot` under `edits` (or None) with the formula.

    Emits RenderStarted, then per frame WindowStarted, StepDone and FramesReady (linear RGB in the
    model's exposure, like the network's frames), then RenderFinished; RenderCancelled when
    `cancel` is set between frames; RenderFailed (and re-raises) on an error. Prompts and the
    reference frame do not apply (`base_dir` is accepted for the Renderer's signature).
    """
    from x2video.sampling.renderer import plain_conditioning
    from x2video.sampling.tiers import formula_frame

    emit = on_event if on_event is not None else (lambda e: None)
    start, stop = settings.frames if settings.frames is not None else (0, shot.num_frames)
    done: list[int] = []
    t0 = time.perf_counter()
    try:
        if not 0 <= start < stop <= shot.num_frames:
            raise ValueError(f"frame range [{start}, {stop}) outside the shot's {shot.num_frames} frames")
        if edits is not None:
            from x2video.edits import apply_edits
        emit(RenderStarted(num_frames=stop - start, num_windows=stop - start, levels=[1], tier="formula", reason=reason))
        for i, t in enumerate(range(start, stop)):
            if cancel is not None and cancel.cancelled:
                emit(RenderCancelled(frames_done=list(done)))
                return
            emit(WindowStarted(index=i, frames=[t], mode="key", level=1))
            tw = time.perf_counter()
            cond = plain_conditioning(shot, t) if edits is None else apply_edits(shot, edits, t)
            rgb = formula_frame(cond)  # (H, W, 3) linear
            emit(StepDone(window=i, step=1, steps=1))
            done.append(t)
            emit(FramesReady(window=i, frames={t: np.asarray(rgb, np.float32)}, level=1, mode="key", seconds=time.perf_counter() - tw))
    except Exception as exc:
        emit(RenderFailed(error=f"{type(exc).__name__}: {exc}"))
        raise
    emit(RenderFinished(num_frames=len(done), seconds=time.perf_counter() - t0))
