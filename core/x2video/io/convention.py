"""Turning decoded image data into the in-memory channel convention of docs/ARCHITECTURE.md (and back for writers).

Conversions, per channel, for float (EXR) and integer (PNG/JPG/TIFF, "LDR") files:

- albedo, irradiance, rgb and the passes (emission, diffuse_color, glossy): EXR linear as stored; LDR sRGB-decoded (``ldr_decode="srgb"``) or with
  the XRGB release's plain power 2.2 (``ldr_decode="gamma2.2"``, used by the XRGB loader).
- normal: EXR normalised; LDR ``2v-1`` then normalised (zero vectors stay zero).
- roughness, metallic, depth: one component (from a one-channel file or the first of R/G/B).
- ids: raw 32-bit EXR integers, rounded floats, or LDR values times 255/65535.

Every channel then goes through `sanitize`: NaN/Inf become 0 with a warning that counts them,
and values are clamped to the channel's range in `x2video.channels.SPECS`.
"""
from __future__ import annotations

import warnings
from typing import Sequence

import numpy as np

from x2video.channels import SPECS, srgb_to_linear
from x2video.io.image import ImageData

#: the extra per-frame field a shot folder may carry besides SPECS: forward motion in pixels
MOTION_SUFFIXES = ("X", "Y")
#: component-name candidates tried in order when a file does not use our own suffixes
_CANDIDATES_3 = (("R", "G", "B"), ("X", "Y", "Z"), ("r", "g", "b"), ("x", "y", "z"))
_CANDIDATES_1 = ("Y", "R", "Z", "X", "V", "id", "A", "r", "y", "z", "x")


class ChannelFormatError(ValueError):
    """An image holds the wrong number or kind of channels for what it should contain."""


def pick_components(img: ImageData, name: str, n: int, suffixes: Sequence[str]) -> np.ndarray:
    """(H, W, n) float array of the components of `img` that hold channel `name`, found by name."""
    have = set(img.channel_names)
    if n == 1:
        for c in (*suffixes, *_CANDIDATES_1):
            if c in have:
                return img.stack([c])
        colour = [c for c in img.channel_names if c not in ("A", "a")]
        if len(colour) in (1, 3, 4):
            return img.stack([colour[0]])
    else:
        for cand in (tuple(suffixes), *_CANDIDATES_3):
            if len(cand) == n and all(c in have for c in cand):
                return img.stack(cand)
        colour = [c for c in img.channel_names if c not in ("A", "a")]
        if len(colour) == n:
            return img.stack(colour)
    raise ChannelFormatError(
        f"{img.path}: cannot take the {n} component(s) of {name!r} from channels {', '.join(img.channel_names)}"
        f" (expected {'/'.join(suffixes)})"
    )


def to_memory(name: str, img: ImageData, *, ldr_decode: str = "srgb", where: str | None = None) -> np.ndarray:
    """Channel `name` of one decoded image file in memory convention (float32 or int32 (H, W, C))."""
    where = where or img.path
    if name == "motion":
        return pick_components(img, name, 2, MOTION_SUFFIXES).astype(np.float32)
    spec = SPECS[name]
    ldr = img.max_int is not None
    a = pick_components(img, name, spec.components, spec.suffixes) if name != "ids" else None
    if name == "ids":
        raw = _pick_raw_id(img)
        if raw.dtype.kind in "ui":
            return raw.astype(np.int32)[..., None]
        raw = np.nan_to_num(raw.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        if ldr:
            raw = raw * img.max_int
        return np.clip(np.rint(raw), 0, 2**31 - 1).astype(np.int32)[..., None]
    assert a is not None
    a = zero_nonfinite(a, where, name)
    if ldr:
        if name in ("albedo", "irradiance", "rgb", "emission", "diffuse_color", "glossy", "glossy_color"):
            a = srgb_to_linear(a) if ldr_decode == "srgb" else np.power(np.clip(a, 0, 1), 2.2, dtype=np.float32)
        elif name == "normal":
            a = a * 2.0 - 1.0
    return sanitize(name, a, where, check_finite=False)


def _pick_raw_id(img: ImageData) -> np.ndarray:
    for c in ("id", "Y", "R", "X", "V", "r"):
        if c in img.planes:
            return img.planes[c]
    if len(img.channel_names) >= 1:
        return img.planes[img.channel_names[0]]
    raise ChannelFormatError(f"{img.path}: no channel to read object ids from")


def zero_nonfinite(a: np.ndarray, where: str, name: str) -> np.ndarray:
    """NaN/Inf -> 0, with a warning naming `where` and counting them."""
    bad = ~np.isfinite(a)
    n = int(bad.sum())
    if n:
        warnings.warn(f"{where}: {n} NaN/Inf value(s) in {name!r} set to 0", RuntimeWarning, stacklevel=3)
        a = np.where(bad, 0.0, a).astype(np.float32)
    return a


def normalize(v: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Unit vectors along the last axis; zero vectors stay zero (torch.nn.functional.normalize)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return (v / np.maximum(n, eps)).astype(np.float32)


def sanitize(name: str, a: np.ndarray, where: str, *, check_finite: bool = True) -> np.ndarray:
    """Zero non-finite values (warning), clamp to the channel's range, normalise normals."""
    spec = SPECS[name]
    if spec.dtype == "int32":
        return np.asarray(a, dtype=np.int32)
    a = np.asarray(a, dtype=np.float32)
    if check_finite:
        a = zero_nonfinite(a, where, name)
    if name == "normal":
        a = normalize(a)
    if spec.lo is not None or spec.hi is not None:
        a = np.clip(a, spec.lo, spec.hi)
    return a.astype(np.float32, copy=False)


# -- the XRGB release's irradiance exposure ----------------------------------------------------
# zheng95z/rgbx, x2rgb/load_image.py (commit 168f2d7), load_exr_image(tonemaping=True):
#   lum = 0.2125 R + 0.7154 G + 0.0721 B; lum_mean = exp(mean(log(max(lum, 1e-6))))
#   Y <- Y * 0.18 / max(lum_mean, 1e-6)   (in Yxy, so chromaticity is kept: a plain scale of RGB)
# and x2rgb/gradio_demo_x2rgb.py loads irradiance EXR with tonemaping=True, clamp=True.
# We compute lum_mean once per shot (over its frames), not per frame.
LUM_WEIGHTS = np.array([0.2125, 0.7154, 0.0721], dtype=np.float32)


def log_luminance_sum(irradiance: np.ndarray) -> tuple[float, int]:
    """(sum of log(max(lum, 1e-6)), pixel count) of one (H, W, 3) linear irradiance frame."""
    lum = np.asarray(irradiance, dtype=np.float32) @ LUM_WEIGHTS  # (H, W)
    return float(np.log(np.maximum(lum, 1e-6)).sum(dtype=np.float64)), int(lum.size)


def exposure_scale(log_sum: float, count: int) -> float:
    """The XRGB exposure factor 0.18 / geometric-mean luminance from accumulated log sums."""
    if count <= 0:
        return 1.0
    lum_mean = float(np.exp(log_sum / count))
    return 0.18 / max(lum_mean, 1e-6)


def scale_irradiance(name: str, a: np.ndarray, scale: float) -> np.ndarray:
    """Channel `name`'s frame `a` with a shot's irradiance normalisation `scale` applied (only irradiance changes)."""
    return a * np.float32(scale) if name == "irradiance" and scale != 1.0 else a
