"""The conditioning latents a window's UNet reads (`RenderModel.encode_frames`): which slot holds what, and how each
frame's channels fill them (`x2video.model.inputs` draws the layout). A part of `X2VideoModel`, kept apart from its
construction, engine and sampling calls.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import torch

from x2video.conditioning.frame import FrameConditioning
from x2video.model.shading import classical_shading, shading_available
from x2video.model.unet import INTRINSIC_CHANNELS
from x2video.model.vae import area_downsample, images_to_tensor, irradiance_to_unit, to_vae_range

#: VAE-encoded intrinsic channels and their slots in the conditioning latents
_VAE_SLOTS = {"albedo": 0, "normal": 4, "roughness": 8, "metallic": 12}
#: channels an "A|M|R masked out" edit removes inside its mask
_AMR = ("albedo", "roughness", "metallic")
_IRR_SLOT = 16
_MASK_SLOT = INTRINSIC_CHANNELS  # 19
_SHADING_SLOT = INTRINSIC_CHANNELS + 1  # 20


class ConditioningLatents:
    """`encode_frames` and the shading-prior image, over what `X2VideoModel` holds (config, device, dtype, encoders)."""

    config: Any
    device: torch.device
    dtype: torch.dtype
    downsample: int
    cond_channels: int

    def _encode_channels(self, images: list[np.ndarray]) -> torch.Tensor:
        raise NotImplementedError

    @torch.no_grad()
    def encode_frames(self, frames: Sequence[FrameConditioning]) -> torch.Tensor:
        if not frames:
            raise ValueError("encode_frames: no frames")
        sizes = {f.size for f in frames}
        if len(sizes) != 1:
            raise ValueError(f"encode_frames: frames differ in size: {sorted(sizes)}")
        (H, W), f = sizes.pop(), self.downsample
        if H % f or W % f:
            raise ValueError(f"frame {frames[0].frame_index}: size {H}x{W} is not a multiple of the VAE factor {f}")
        h, w = H // f, W // f
        scales = self.config.latent_scales
        out = torch.zeros(len(frames), self.cond_channels, h, w, device=self.device, dtype=self.dtype)  # (N, C_cond, h, w)
        for fr in frames:
            if np.shape(fr.amr_mask) != (H, W):
                raise ValueError(f"frame {fr.frame_index}: amr_mask is {np.shape(fr.amr_mask)}, expected {(H, W)}")
        masks = torch.from_numpy(np.stack([np.asarray(fr.amr_mask, np.float32) for fr in frames]))[:, None]  # (N, 1, H, W)
        masks_lat = area_downsample(masks.to(self.device, self.dtype), (h, w))  # (N, 1, h, w)
        out[:, _MASK_SLOT : _MASK_SLOT + 1] = masks_lat
        for name, slot in _VAE_SLOTS.items():
            idx = [i for i, fr in enumerate(frames) if fr.channels.get(name) is not None]
            if idx:
                imgs = [to_vae_range(name, self._checked(frames[i], name, H, W)) for i in idx]
                z = self._encode_channels(imgs) * scales[name]  # (n, 4, h, w)
                if name in _AMR:  # masked-out regions are zero latents, like a dropped channel
                    z = z * (1 - masks_lat[idx])
                out[idx, slot : slot + 4] = z
        idx = [i for i, fr in enumerate(frames) if fr.channels.get("irradiance") is not None]
        if idx:
            irr = images_to_tensor([irradiance_to_unit(self._checked(frames[i], "irradiance", H, W)) for i in idx], self.device, self.dtype)
            out[idx, _IRR_SLOT : _IRR_SLOT + 3] = area_downsample(irr, (h, w))  # (n, 3, h, w) in [-1, 1]
        if self.config.shading_prior:
            idx = [i for i, fr in enumerate(frames) if shading_available(fr.channels)]
            if idx:
                imgs = [to_vae_range("shading", self.prior_image(frames[i])) for i in idx]
                z = self._encode_channels(imgs) * scales["rgb"]  # (n, 4, h, w)
                out[idx, _SHADING_SLOT : _SHADING_SLOT + 4] = z * (1 - masks_lat[idx])  # zero where A|M|R masked out
        return out

    def prior_image(self, frame: FrameConditioning) -> np.ndarray:
        """(H, W, 3) linear image the shading-prior slot encodes for `frame` (`ModelConfig.prior`): its classical
        shading, or tier 1's frame (`frame.prior`), zero inside the A|M|R mask either way."""
        if self.config.prior == "shading":
            return classical_shading(frame.channels, frame.amr_mask)
        if frame.prior is None:
            raise ValueError(f"frame {frame.frame_index}: this model samples its residual over tier 1's frame (config prior "
                             f"'tier1'), and the frame carries none; render through x2video.Renderer, which makes it")
        H, W = frame.size
        if np.shape(frame.prior) != (H, W, 3):
            raise ValueError(f"frame {frame.frame_index}: tier 1's frame is {np.shape(frame.prior)}, expected {(H, W, 3)}")
        keep = (np.asarray(frame.amr_mask, np.float32) <= 0.5)[..., None]
        return (np.asarray(frame.prior, np.float32) * keep).astype(np.float32)

    @property
    def prior(self) -> str:
        """What the shading-prior slot holds (`ModelConfig.prior`): "shading" or "tier1"."""
        return self.config.prior

    @staticmethod
    def _checked(frame: FrameConditioning, name: str, H: int, W: int) -> np.ndarray:
        x = frame.channels[name]
        assert x is not None
        if x.shape[:2] != (H, W):
            raise ValueError(f"frame {frame.frame_index}: channel {name!r} is {x.shape[0]}x{x.shape[1]}, mask is {H}x{W}")
        if not np.all(np.isfinite(x)):  # as the loaders and tiers 0/1 do: NaN/Inf count as 0, with a warning
            from x2video.io.convention import zero_nonfinite

            x = zero_nonfinite(np.asarray(x, np.float32), f"frame {frame.frame_index}", name)
        return x
