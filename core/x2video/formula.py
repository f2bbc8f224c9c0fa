"""The formula, tier 0 of "no more model than a scene needs": albedo x irradiance of one frame's channels.

Exact for diffuse light and free: no network, no weights, any frame size. It sits under everything that renders:
tier 0 is it (`x2video.tiers.formula`), tier 1's net corrects it (`x2video.model.residual`), large frames come back
onto it (`x2video.conditioning.network`). The plain product, not `x2video.model.shading.classical_shading`, whose
grey-world GGX term overshoots a path tracer's energy-conserving BSDF.
"""
from __future__ import annotations

from typing import Mapping, Protocol

import numpy as np


class Frame(Protocol):
    """What `formula_frame` reads of a frame's conditioning (`x2video.conditioning.frame.FrameConditioning`)."""

    channels: Mapping[str, np.ndarray | None]
    amr_mask: np.ndarray


def finite(v: np.ndarray) -> np.ndarray:
    """float32 `v` with NaN and +-Inf set to 0 (what the loaders do with them, `x2video.io.convention.zero_nonfinite`)."""
    v = np.asarray(v, np.float32)
    return v if np.isfinite(v).all() else np.where(np.isfinite(v), v, np.float32(0))


def frame_shape(ch: Mapping[str, np.ndarray | None], shape: tuple[int, int] | None) -> tuple[int, int]:
    present = [np.asarray(v).shape[:2] for v in ch.values() if v is not None]
    if present:
        return present[0]
    if shape is None:
        raise ValueError("every channel is dropped: give the frame's (H, W) as `shape`")
    return tuple(shape)[:2]  # type: ignore[return-value]


def formula(ch: Mapping[str, np.ndarray | None], shape: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W, 3) albedo x irradiance (zeros when either is missing; `shape` = (H, W) when every channel is):
    tier 0 and the net's base. Non-finite values count as 0, albedo is clipped to [0, 1], irradiance to >= 0."""
    al, ir = ch.get("albedo"), ch.get("irradiance")
    if al is None or ir is None:
        return np.zeros((*frame_shape(ch, shape), 3), np.float32)
    return (np.clip(finite(al), 0, 1) * np.maximum(finite(ir), 0)).astype(np.float32)


def formula_frame(cond: Frame) -> np.ndarray:
    """Tier 0: (H, W, 3) linear albedo x irradiance of one frame's (edited) conditioning, zero inside A|M|R regions."""
    out = formula(cond.channels, np.shape(cond.amr_mask)[:2] if np.size(cond.amr_mask) else None)
    return out * (np.asarray(cond.amr_mask, np.float32) <= 0.5)[..., None] if cond.amr_mask.size else out
