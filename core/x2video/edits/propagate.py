"""Propagating one painted mask frame along a shot with OpenCV DIS optical flow on albedo/normal.

The result is a dict of per-frame arrays to store with `Mask.paint` (so applying edits stays a
cheap pure function and the project file keeps exactly what the person saw).
"""
from __future__ import annotations

from typing import Callable, Iterable

import cv2
import numpy as np

from x2video.channels import linear_to_srgb
from x2video.shot import Shot


def flow_image(shot: Shot, t: int) -> np.ndarray:
    """uint8 (H, W) image the flow is computed on: mean of sRGB albedo luminance and normal shading."""
    parts = []
    if shot.has("albedo"):
        parts.append(linear_to_srgb(shot.channel("albedo", t)).mean(-1))
    if shot.has("normal"):
        n = shot.channel("normal", t)
        parts.append(np.clip(0.5 + 0.5 * (n @ np.array([0.3, 0.5, 0.8], np.float32)) / 1.0, 0, 1))
    if not parts:
        raise ValueError(f"mask propagation needs an albedo or normal channel; shot {shot.info.source!r} has {shot.channels}")
    return np.round(np.mean(parts, axis=0) * 255).astype(np.uint8)


def warp(image: np.ndarray, flow_back: np.ndarray, border: int = cv2.BORDER_CONSTANT) -> np.ndarray:
    """Pull `image` (H, W[, C]) along `flow_back` (H, W, 2): out(x) = image(x + flow_back(x)), bilinear."""
    h, w = flow_back.shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(image.astype(np.float32), gx + flow_back[..., 0], gy + flow_back[..., 1], cv2.INTER_LINEAR, borderMode=border, borderValue=0)


def compose(step_back: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """Flow from frame t to t0, given step_back (t -> t-1) and acc (t-1 -> t0); both (H, W, 2)."""
    return step_back + warp(acc, step_back, cv2.BORDER_REPLICATE)


def propagate_mask(
    shot: Shot,
    mask: np.ndarray,
    t0: int,
    frames: Iterable[int] | None = None,
    *,
    preset: int = cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
    on_progress: Callable[[int, int], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> dict[int, np.ndarray]:
    """Carry `mask` (H, W) painted on frame `t0` to the other frames (default: all), step by step.

    Each step computes DIS flow from frame t back to the previous one and chains it onto the
    flow back to t0, so the painted mask is resampled once per frame (no blur build-up); a binary
    input mask stays binary (>= 0.5).
    Returns {frame: (H, W) float32} including t0. `on_progress(done, total)` is called per
    frame; `should_stop()` returning True ends early with what was done.
    """
    n = shot.num_frames
    if not 0 <= t0 < n:
        raise ValueError(f"propagate: frame {t0} outside the shot's {n} frames")
    mask = np.asarray(mask, np.float32)
    if mask.shape != shot.size:
        raise ValueError(f"propagate: mask has shape {mask.shape}, the shot is {shot.size}")
    wanted = set(range(n)) if frames is None else {int(f) for f in frames}
    binary = bool(np.isin(mask, (0.0, 1.0)).all())
    dis = cv2.DISOpticalFlow_create(preset)
    out = {t0: mask.copy()}
    fwd_end = max([f for f in wanted if f > t0], default=t0)
    back_end = min([f for f in wanted if f < t0], default=t0)
    total = (fwd_end - t0) + (t0 - back_end)
    done = 0
    for step, end in ((1, fwd_end), (-1, back_end)):
        acc, img_cur = np.zeros((*mask.shape, 2), np.float32), flow_image(shot, t0)  # (H, W, 2) flow to t0
        for t in range(t0 + step, end + step, step):
            if should_stop is not None and should_stop():
                return {k: v for k, v in out.items() if k in wanted}
            img_next = flow_image(shot, t)
            step_back = dis.calc(img_next, img_cur, None)  # (H, W, 2): pixel of frame t -> its place in the previous one
            acc = compose(step_back, acc)
            cur = warp(mask, acc)
            if binary:
                cur = (cur >= 0.5).astype(np.float32)
            out[t] = cur
            img_cur = img_next
            done += 1
            if on_progress is not None:
                on_progress(done, total)
    return {k: v for k, v in out.items() if k in wanted}
