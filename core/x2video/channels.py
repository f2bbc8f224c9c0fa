"""Intrinsic channel names, their in-memory conventions, and colour transfer functions (docs/ARCHITECTURE.md "Channel convention")."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The five intrinsic channels the model reads, in UNet input order (XRGB layout).
INTRINSIC = ("albedo", "normal", "roughness", "metallic", "irradiance")
#: Channels a shot may carry besides the intrinsic ones.
#: emission: light the surface emits itself (Blender's Emit + Env passes), linear HDR, in the shot's exposure.
#: diffuse_color: the colour Cycles divided the diffuse light passes by (DiffCol: the base colour times what the BSDF
#: keeps diffuse); glossy: the glossy and transmitted light (GlossCol x (GlossDir + GlossInd) + TransCol x (TransDir +
#: TransInd)), linear HDR in rgb's units as emission. With irradiance they split rgb as Cycles does (`PASSES`).
#: glossy_color: the colour Cycles divided the glossy light passes by (GlossCol: about 0.04 on a dielectric, the base
#: colour on a metal), what a metallic edit changes the glossy term by (`x2video.base.passes`).
EXTRA = ("ids", "rgb", "depth", "emission", "diffuse_color", "glossy", "glossy_color")
#: the terms of a path-traced frame besides albedo x irradiance: rgb = diffuse_color x irradiance + glossy + emission
#: (irradiance unnormalised), what the formula over the base rebuilds (`x2video.base.passes`)
PASSES = ("diffuse_color", "glossy", "emission", "glossy_color")
#: the passes that are light (scaled with irradiance by the light operations, `x2video.edits.ops`)
LIGHT_PASSES = ("glossy", "emission")
ALL = INTRINSIC + EXTRA
#: The intrinsic channels the VAE encodes (irradiance is area-downsampled to latent size instead).
VAE_ENCODED = INTRINSIC[:4]


@dataclass(frozen=True)
class ChannelSpec:
    """How one channel is stored in memory: float32 (or int32 for ids) arrays of shape (H, W, components)."""

    name: str
    components: int
    #: names of the components inside a multi-channel EXR (``albedo.R`` ...)
    suffixes: tuple[str, ...]
    lo: float | None
    hi: float | None
    dtype: str = "float32"


SPECS: dict[str, ChannelSpec] = {
    "albedo": ChannelSpec("albedo", 3, ("R", "G", "B"), 0.0, 1.0),
    "normal": ChannelSpec("normal", 3, ("X", "Y", "Z"), -1.0, 1.0),
    "roughness": ChannelSpec("roughness", 1, ("Y",), 0.0, 1.0),
    "metallic": ChannelSpec("metallic", 1, ("Y",), 0.0, 1.0),
    "irradiance": ChannelSpec("irradiance", 3, ("R", "G", "B"), 0.0, None),
    "rgb": ChannelSpec("rgb", 3, ("R", "G", "B"), 0.0, None),
    "ids": ChannelSpec("ids", 1, ("id",), 0, None, dtype="int32"),
    "depth": ChannelSpec("depth", 1, ("Z",), 0.0, None),
    "emission": ChannelSpec("emission", 3, ("R", "G", "B"), 0.0, None),
    "diffuse_color": ChannelSpec("diffuse_color", 3, ("R", "G", "B"), 0.0, 1.0),
    "glossy": ChannelSpec("glossy", 3, ("R", "G", "B"), 0.0, None),
    "glossy_color": ChannelSpec("glossy_color", 3, ("R", "G", "B"), 0.0, 1.0),
}


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding, for values in [0, 1]."""
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding; values are clipped to [0, 1] first."""
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


def tonemap(x: np.ndarray) -> np.ndarray:
    """The project's one display transform for linear HDR radiance: clip to [0, 1], then sRGB.

    Everything that compares a render with a ground truth (procedural renderer, shading
    prior, metrics) uses this function, so "tone-mapped" means the same thing everywhere.
    """
    return linear_to_srgb(x)
