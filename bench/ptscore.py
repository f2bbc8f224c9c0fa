"""Scoring against path-traced ground truth, shared by `bench.pathtraced` and `bench.pareto`.

A shot's frames are compared in the shot's own units: the renderer's frames are in the model's
exposure (the shot's irradiance normalisation), so they are divided by `shot.info.irradiance_scale`
before display; the ground truth (Cycles' Combined) and any Cycles re-render are already in those
units. The truth is the shot's truth apart (``truth/``: more samples, another noise seed than the passes the
tiers read) when it has one, else its rgb (`x2video.io.truth`). PSNR and SSIM are on display images (`x2video.channels.tonemap`: clip, sRGB), TC is the
warping error over the ground truth's (DIS flow on the ground truth: docs/ARCHITECTURE.md "Measuring it").
"""
from __future__ import annotations

import time
from typing import Any, Sequence

import numpy as np

from x2video.channels import tonemap
from x2video.io.truth import ground_truth
from x2video.io.truth import summary as truth_summary
from x2video.metrics.image import psnr, ssim
from x2video.metrics.temporal import temporal_consistency
from x2video.render.events import FramesReady
from x2video.render.settings import RenderSettings


def display(frames: Sequence[np.ndarray], scale: float = 1.0) -> list[np.ndarray]:
    """Display images of linear frames divided by `scale` (a renderer's frames: the shot's irradiance_scale)."""
    return [tonemap(np.asarray(f, np.float32) / scale) for f in frames]


def truth(shot: Any, frames: int | None = None) -> list[np.ndarray]:
    """Display images of the shot's ground truth, first `frames` frames (default all): its truth apart (``truth/``,
    `x2video dataset truth`) when it has one, else its rgb channel (`truth_label` says which)."""
    n = shot.num_frames if frames is None else min(frames, shot.num_frames)
    gt = ground_truth(shot)
    return [tonemap(gt.frame(t)) for t in range(n)]


def truth_label(shots: Sequence[Any]) -> str:
    """What the shots were scored against, for a result's "truth" field: 'apart, 64 spp seed 1' (``truth/``) or
    "the passes' own Combined" (one label, or each with its count when the shots differ)."""
    return truth_summary(ground_truth(s).label for s in shots)


def score(disp: Sequence[np.ndarray], gts: Sequence[np.ndarray]) -> dict[str, float | None]:
    """{'psnr', 'ssim' (means over frames), 'tc' (None under two frames)} of display images against the truth's."""
    if len(disp) != len(gts):
        raise ValueError(f"scoring: {len(disp)} frames against {len(gts)} of ground truth")
    return {"psnr": float(np.mean([psnr(p, g) for p, g in zip(disp, gts)])),
            "ssim": float(np.mean([ssim(p, g) for p, g in zip(disp, gts)])),
            "tc": float(temporal_consistency(list(disp), list(gts)).tc) if len(gts) >= 2 else None}


def render_timed(renderer: Any, shot: Any, settings: RenderSettings, edits: Any = None, **options: Any) -> tuple[list[np.ndarray], float]:
    """(linear frames of `settings.frames` (default all) in order, wall seconds of `renderer.render`, given `options`)."""
    frames: dict[int, np.ndarray] = {}

    def on_event(e: Any) -> None:
        if isinstance(e, FramesReady):
            frames.update(e.frames)

    t0 = time.perf_counter()
    renderer.render(shot, edits, settings, on_event, **options)
    secs = time.perf_counter() - t0
    start, stop = settings.frames if settings.frames is not None else (0, shot.num_frames)
    missing = [t for t in range(start, stop) if t not in frames]
    if missing:
        raise RuntimeError(f"{shot.info.source}: the render delivered no frame {missing[0]} ({len(missing)} missing)")
    return [frames[t] for t in range(start, stop)], secs
