"""The VAE side of the conditioning (paper Sec. Model Overview): channel -> VAE range maps, irradiance mapping, latent scales.

Every channel goes through `diffusers.AutoencoderKL` (posterior mode) as a 3-channel image
in [-1, 1], then is multiplied by its own latent scaling factor, except irradiance, which
(as in XRGB) is not VAE-encoded: it is mapped to [-1, 1] and area-downsampled to the latent
size. Mappings to the VAE's [-1, 1]:

    albedo     linear [0,1]  -> sRGB-encode -> *2-1            (perceptual, like an RGB photo)
    rgb        linear HDR    -> channels.tonemap (clip, sRGB) -> *2-1; decode inverts to linear [0,1]
    normal     unit xyz [-1,1] as is
    roughness, metallic  [0,1] -> *2-1, the one channel replicated to 3
    irradiance linear HDR >= 0 -> Reinhard x/(1+x) -> sRGB-encode -> *2-1   (`irradiance_to_unit`)
               0 -> -1, 1 -> 0.47, 4 -> 0.81, inf -> 1: never clips highlights, monotonic,
               inverted exactly by `unit_to_irradiance`.
"""
from __future__ import annotations

from typing import Iterable

import numpy as np
import torch
import torch.nn.functional as F
from diffusers import AutoencoderKL

from x2video.channels import linear_to_srgb, srgb_to_linear, tonemap
from x2video.model.config import LATENT_SCALE_KEYS, VAEConfig


def build_vae(cfg: VAEConfig, mid_attention: bool = True) -> AutoencoderKL:
    """A freshly initialised `AutoencoderKL` (3-channel images in [-1, 1], `latent_channels` latents);
    `mid_attention=False` leaves out the mid-blocks' self-attention (the distilled channel encoder)."""
    k = len(cfg.block_out_channels)
    return AutoencoderKL(
        in_channels=3,
        out_channels=3,
        down_block_types=("DownEncoderBlock2D",) * k,
        up_block_types=("UpDecoderBlock2D",) * k,
        block_out_channels=cfg.block_out_channels,
        layers_per_block=cfg.layers_per_block,
        latent_channels=cfg.latent_channels,
        norm_num_groups=cfg.norm_num_groups,
        mid_block_add_attention=mid_attention,
    )


# -- channel <-> VAE range (numpy, (H, W, C) float32) ------------------------------------
def irradiance_to_unit(x: np.ndarray) -> np.ndarray:
    """Linear HDR irradiance (>= 0) -> [-1, 1]: Reinhard x/(1+x), sRGB-encode, *2-1."""
    x = np.maximum(np.nan_to_num(np.asarray(x, np.float32), nan=0.0, posinf=1e6), 0.0)
    return linear_to_srgb(x / (1.0 + x)) * 2.0 - 1.0


def unit_to_irradiance(y: np.ndarray) -> np.ndarray:
    """Inverse of `irradiance_to_unit` (values at +1 map to a large finite irradiance)."""
    r = np.clip(srgb_to_linear((np.asarray(y, np.float32) + 1.0) / 2.0), 0.0, 1.0 - 1e-6)
    return (r / (1.0 - r)).astype(np.float32)


def to_vae_range(name: str, x: np.ndarray) -> np.ndarray:
    """One channel (H, W, C) in the memory convention of docs/ARCHITECTURE.md -> (H, W, 3) float32 in [-1, 1] for the VAE."""
    x = np.asarray(x, np.float32)
    if x.ndim == 2:
        x = x[..., None]
    if name == "albedo":
        y = linear_to_srgb(x) * 2 - 1
    elif name in ("rgb", "shading"):
        y = tonemap(x) * 2 - 1
    elif name == "normal":
        y = np.clip(x, -1, 1)
    elif name in ("roughness", "metallic"):
        y = np.repeat(np.clip(x[..., :1], 0, 1), 3, axis=-1) * 2 - 1
    else:
        raise ValueError(f"channel {name!r} is not VAE-encoded")
    if y.shape[-1] != 3:
        raise ValueError(f"channel {name!r}: expected 3 components after mapping, got shape {x.shape}")
    return y.astype(np.float32)


def from_vae_range_rgb(y: torch.Tensor) -> torch.Tensor:
    """Decoder output (N, 3, H, W) in [-1, 1] (sRGB-encoded) -> (N, H, W, 3) linear RGB in [0, 1]."""
    s = ((y.float() + 1) / 2).clamp(0, 1).permute(0, 2, 3, 1)  # (N, H, W, 3)
    return torch.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def area_downsample(x: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """(N, C, H, W) -> (N, C, h, w) by area averaging (irradiance and masks to latent size)."""
    return F.adaptive_avg_pool2d(x, size)


# -- encoding ---------------------------------------------------------------------------
def images_to_tensor(images: Iterable[np.ndarray], device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """(H, W, 3) arrays -> (N, 3, H, W) tensor."""
    arr = np.stack(list(images)).astype(np.float32)  # (N, H, W, 3)
    return torch.from_numpy(arr).permute(0, 3, 1, 2).to(device=device, dtype=dtype)


@torch.no_grad()
def encode_mode(vae: AutoencoderKL, x: torch.Tensor, batch: int = 8) -> torch.Tensor:
    """(N, 3, H, W) in [-1, 1] -> (N, 4, H/f, W/f) posterior mode (unscaled), in chunks of `batch`."""
    out = [vae.encode(x[i : i + batch]).latent_dist.mode() for i in range(0, x.shape[0], batch)]
    return torch.cat(out)


@torch.no_grad()
def measure_latent_scales(vae: AutoencoderKL, samples: dict[str, Iterable[np.ndarray]], device: torch.device | str = "cpu") -> dict[str, float]:
    """Per-channel latent scaling factor 1/std of the posterior-mode latents over `samples`
    (name -> (H, W, C) arrays in memory convention; names in LATENT_SCALE_KEYS). Channels
    without samples get 1.0. Store the result in `ModelConfig.latent_scales`."""
    dev = torch.device(device)
    dtype = next(vae.parameters()).dtype
    scales: dict[str, float] = {}
    for name in LATENT_SCALE_KEYS:
        imgs = [to_vae_range(name, a) for a in samples.get(name, [])]
        if not imgs:
            scales[name] = 1.0
            continue
        z = encode_mode(vae, images_to_tensor(imgs, dev, dtype))
        std = float(z.float().std())
        if not np.isfinite(std) or std <= 0:
            raise ValueError(f"latents of {name!r} have std {std}; cannot derive a scaling factor")
        scales[name] = 1.0 / std
    return scales
