"""Qt-free display transforms: every viewer mode (channel, overlay, side-by-side) to an 8-bit sRGB image."""
from __future__ import annotations

import numpy as np

from x2video.channels import linear_to_srgb, tonemap

#: Viewer modes in the order the channel switcher lists them.
VIEW_MODES = (
    "albedo",
    "normal",
    "roughness",
    "metallic",
    "irradiance",
    "ids",
    "masks",
    "reference",
    "rendered",
    "side-by-side",
)

#: Distinct, readable colours for masks (RGB 0-255), cycled by mask index.
MASK_COLOURS = (
    (255, 99, 71),
    (65, 179, 247),
    (124, 222, 90),
    (255, 205, 60),
    (190, 120, 255),
    (255, 140, 200),
    (70, 230, 210),
    (240, 240, 240),
)


def to_u8(rgb01: np.ndarray) -> np.ndarray:
    """float (H, W, 3) display values in [0, 1] -> contiguous uint8 (H, W, 3)."""
    return np.ascontiguousarray((np.clip(rgb01, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))


def ids_palette(ids: np.ndarray) -> np.ndarray:
    """int (H, W[, 1]) object ids -> uint8 (H, W, 3) with a stable pseudo-random colour per id, 0 black."""
    ids = np.asarray(ids).reshape(ids.shape[0], ids.shape[1]).astype(np.int64)
    h = (ids * 2654435761) & 0xFFFFFFFF  # Knuth multiplicative hash, per id
    rgb = np.stack([(h >> 16) & 255, (h >> 8) & 255, h & 255], axis=-1).astype(np.float32)
    rgb = 60.0 + rgb * (195.0 / 255.0)  # keep colours away from black
    rgb[ids == 0] = 0.0
    return rgb.astype(np.uint8)


def channel_to_u8(name: str, arr: np.ndarray | None, size: tuple[int, int]) -> np.ndarray:
    """One channel in memory convention -> uint8 (H, W, 3); a missing channel shows as a dark checkerboard."""
    if arr is None:
        return checker(size)
    if name == "albedo":
        return to_u8(linear_to_srgb(arr))
    if name == "normal":
        return to_u8(arr * 0.5 + 0.5)
    if name in ("roughness", "metallic", "depth"):
        g = arr[..., :1]
        if name == "depth":
            g = g / max(float(np.nanmax(g)), 1e-6)
        return to_u8(np.repeat(g, 3, axis=-1))
    if name == "ids":
        return ids_palette(arr)
    # irradiance, rgb, rendered output, reference: linear HDR
    return to_u8(tonemap(arr))


def checker(size: tuple[int, int], cell: int = 16) -> np.ndarray:
    """uint8 (H, W, 3) dark checkerboard: 'nothing here' (dropped channel, frame not rendered yet)."""
    h, w = size
    yy, xx = np.mgrid[0:h, 0:w]
    v = np.where(((yy // cell) + (xx // cell)) % 2 == 0, 38, 52).astype(np.uint8)
    return np.repeat(v[..., None], 3, axis=-1)


def overlay_masks(base: np.ndarray, masks: list[tuple[np.ndarray, tuple[int, int, int]]], alpha: float = 0.55,
                  dim: float = 0.5) -> np.ndarray:
    """Coloured masks over a uint8 base, drawn as look-dev tools draw a selection: outside every mask the base is
    darkened by `dim` and half desaturated, inside each mask tinted with its colour (`alpha`), and each edge outlined
    in the solid colour with a dark line outside it, so a mask reads on any image. masks: (float/bool (H, W),
    colour) pairs."""
    layers = [(np.asarray(m, dtype=np.float32), np.asarray(c, dtype=np.float32)) for m, c in masks]
    layers = [(m, c) for m, c in layers if m.max(initial=0.0) > 0.0]
    out = base.astype(np.float32)
    if not layers:
        return np.ascontiguousarray(base.astype(np.uint8))
    inside = np.clip(np.max([m for m, _ in layers], axis=0), 0.0, 1.0)[..., None]
    grey = out.mean(axis=-1, keepdims=True)
    out = out * inside + (0.5 * (out + grey) * (1.0 - dim)) * (1.0 - inside)
    for m, c in layers:
        a = (alpha * np.clip(m, 0.0, 1.0))[..., None]
        out = out * (1.0 - a) + c * a
    for m, c in layers:
        sel = m > 0.5
        out[_edge(~sel)] = c * 0.2  # the dark line just outside
        out[_edge(sel)] = c
    return np.ascontiguousarray(np.clip(out, 0, 255).astype(np.uint8))


def _edge(m: np.ndarray) -> np.ndarray:
    """Pixels of a boolean mask with a 4-neighbour outside it."""
    p = np.pad(m, 1, mode="edge")
    inner = p[1:-1, 1:-1] & p[:-2, 1:-1] & p[2:, 1:-1] & p[1:-1, :-2] & p[1:-1, 2:]
    return m & ~inner


def side_by_side(left: np.ndarray, right: np.ndarray, gap: int = 4) -> np.ndarray:
    """Two uint8 (H, W, 3) images next to each other with a thin dark gap."""
    h = max(left.shape[0], right.shape[0])
    out = np.full((h, left.shape[1] + gap + right.shape[1], 3), 20, np.uint8)
    out[: left.shape[0], : left.shape[1]] = left
    out[: right.shape[0], left.shape[1] + gap :] = right
    return out
