"""Qt-free look-dev compositing (issue 43): an A/B wipe, side by side, a false-colour difference, and PSNR.

Images come in display-referred float32 (H, W, 3) in [0, 1] (linear frames through `x2video.channels.tonemap`, the
display transform every metric uses; channels as the viewer shows them), and leave as uint8 for the viewer.
"""
from __future__ import annotations

import cv2
import numpy as np

from x2video_app.state.display import side_by_side, to_u8

#: compare modes, in the order the Compare toolbar lists them
MODES = ("off", "wipe", "side by side", "difference")
#: a display-referred difference this large (in [0, 1]) shows at the top of the false-colour scale
DIFF_FULL_SCALE = 0.25


def wipe(a: np.ndarray, b: np.ndarray, at: float) -> np.ndarray:
    """uint8 (H, W, 3): `a` left of column `at` (a fraction of the width), `b` right of it, a light line between."""
    h, w = a.shape[:2]
    x = int(round(min(max(at, 0.0), 1.0) * w))
    out = np.concatenate([a[:, :x], b[:, x:]], axis=1) if x else b.copy()
    out[:, max(0, x - 1):min(w, x + 1)] = 230
    return np.ascontiguousarray(out)


def difference(a: np.ndarray, b: np.ndarray, full_scale: float = DIFF_FULL_SCALE) -> np.ndarray:
    """uint8 (H, W, 3) false colour (inferno) of the per-pixel mean |a - b| of two display-referred images: black where
    they agree, yellow-white at `full_scale` or more."""
    d = np.abs(a.astype(np.float32) - b.astype(np.float32)).mean(axis=-1)
    g = np.clip(d / full_scale, 0.0, 1.0)
    bgr = cv2.applyColorMap((g * 255.0 + 0.5).astype(np.uint8), cv2.COLORMAP_INFERNO)
    return np.ascontiguousarray(bgr[..., ::-1])


def compose(mode: str, a: np.ndarray, b: np.ndarray, at: float = 0.5) -> np.ndarray:
    """The compare view of display-referred images `a`, `b` in `mode` (one of `MODES` but 'off')."""
    if mode == "wipe":
        return wipe(to_u8(a), to_u8(b), at)
    if mode == "side by side":
        return side_by_side(to_u8(a), to_u8(b))
    if mode == "difference":
        return difference(a, b)
    raise ValueError(f"unknown compare mode {mode!r}; one of {MODES[1:]}")


def psnr_db(image: np.ndarray, truth: np.ndarray) -> float | None:
    """PSNR in dB of two display-referred images (`x2video.metrics.psnr`: what the benchmarks report); None until torch
    is loaded (the metrics package imports it: the window does not, before the model is built)."""
    import sys

    if "torch" not in sys.modules:
        return None
    from x2video.metrics.image import psnr

    return psnr(image, truth)
