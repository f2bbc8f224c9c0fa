"""Carrying a keyframe's shading by optical flow on the G-buffers, where a shot has no depth or camera.

The flow runs on what both frames have without a path trace, a guide image of albedo and normals (DIS optical
flow, OpenCV, as `x2video.metrics.temporal` uses for outside footage), from the frame between to the keyframe; a
pixel is rejected where the flow back does not return it (forward-backward check) or the keyframe's albedo there
is another colour.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from x2video.channels import linear_to_srgb
from x2video.shot import Shot

if TYPE_CHECKING:
    from x2video.base.fill import FillConfig

#: albedo difference (max over RGB, linear) above which a flowed pixel is another surface
ALBEDO_TOLERANCE = 0.08


def guide(shot: Shot, t: int) -> np.ndarray:
    """(H, W) uint8 image for the flow: albedo's sRGB luminance and the normal's x and y, mixed."""
    parts = []
    if shot.has("albedo"):
        parts.append(linear_to_srgb(shot.channel("albedo", t)).mean(-1) * 0.6)
    if shot.has("normal"):
        n = shot.channel("normal", t)
        parts.append((n[..., 0] * 0.5 + 0.5) * 0.2 + (n[..., 1] * 0.5 + 0.5) * 0.2)
    if not parts:
        raise ValueError(f"shot {shot.info.source!r}: filling frame {t} by flow needs albedo or normal")
    g = np.sum(parts, 0) / sum((0.6 if shot.has("albedo") else 0, 0.4 if shot.has("normal") else 0))
    return np.clip(g * 255 + 0.5, 0, 255).astype(np.uint8)


def _flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    return dis.calc(a, b, None)  # (H, W, 2): a(p) ~ b(p + flow)


def warp_by_flow(shot: Shot, t: int, k: int, shading_k: np.ndarray, cfg: FillConfig) -> tuple[np.ndarray, np.ndarray]:
    """Keyframe k's `shading_k` carried onto frame t by G-buffer flow: ((H, W, 3) shading, (H, W) validity)."""
    gt, gk = guide(shot, t), guide(shot, k)
    fwd, bwd = _flow(gt, gk), _flow(gk, gt)
    h, w = shot.size
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    x, y = xs + fwd[..., 0], ys + fwd[..., 1]
    warped = cv2.remap(shading_k, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    back = cv2.remap(bwd, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1e6)
    valid = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    valid &= np.hypot(fwd[..., 0] + back[..., 0], fwd[..., 1] + back[..., 1]) <= cfg.flow_consistency
    if shot.has("albedo"):
        ak = cv2.remap(shot.channel("albedo", k), x, y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        valid &= np.abs(ak - shot.channel("albedo", t)).max(-1) <= ALBEDO_TOLERANCE
    return warped.astype(np.float32), valid
