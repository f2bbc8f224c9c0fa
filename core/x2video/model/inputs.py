"""UNet inputs from latents and one UNet call over windows: shared by sampling (`X2VideoModel.predict_v`) and training.

Conditioning latents from `X2VideoModel.encode_frames` have this channel layout (C_cond):

    [albedo 4 | normal 4 | roughness 4 | metallic 4 | irradiance 3 | union mask 1 | shading 4 (if shading_prior)]
     \\_______________________ 19 "intrinsic" __________________/

and `unet_inputs` interleaves the noisy latent and reference latents into the UNet layout
(see `x2video.model.unet`): [x_t 4 | intrinsic 19 | R 4 | mask 1 | shading 4].
"""
from __future__ import annotations

import functools
from typing import Sequence

import torch
from diffusers import UNet2DConditionModel
from diffusers.schedulers.scheduling_ddim import rescale_zero_terminal_snr

from x2video.model.context import AttnContext
from x2video.model.unet import IMAGE_IN, IMAGE_IN_PRIOR, INTRINSIC_CHANNELS, LATENT, MASK_CHANNELS, REF_CHANNELS, SHADING_CHANNELS

#: what a UNet may output (`ModelConfig.prediction`)
PREDICTIONS = ("v", "sample")


def cond_channels(shading_prior: bool) -> int:
    """C_cond of `encode_frames`: 20, or 24 with the shading prior."""
    return INTRINSIC_CHANNELS + MASK_CHANNELS + (SHADING_CHANNELS if shading_prior else 0)


@functools.lru_cache(maxsize=4)
def sd_alphas_cumprod(num_train_timesteps: int = 1000, beta_start: float = 0.00085, beta_end: float = 0.012) -> torch.Tensor:
    """SD 2.1 scaled-linear betas rescaled to zero terminal SNR (Lin et al. 2024, Alg. 1) -> (T,) float64 alphas_cumprod."""
    betas = torch.linspace(beta_start**0.5, beta_end**0.5, num_train_timesteps, dtype=torch.float64) ** 2
    betas = rescale_zero_terminal_snr(betas)
    return torch.cumprod(1.0 - betas, dim=0)


def v_from_sample(x0: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """v of an x0 prediction at per-frame timesteps t (BN,): v = (sqrt(a) x_t - x0) / sqrt(1 - a).
    With zero terminal SNR a(999) = 0 and v = -x0; 1 - a >= 1 - a(0) = 0.00085, so it never divides by zero."""
    a = sd_alphas_cumprod().to(x_t.device)[t.long()].to(x_t.dtype).view(-1, 1, 1, 1)
    return (a.sqrt() * x_t - x0) / (1 - a).sqrt()


def prior_latents(cond: torch.Tensor) -> torch.Tensor:
    """(BN, 4, h, w) shading-prior latents of (BN, C_cond, h, w) conditioning (zero where the prior is absent)."""
    full = INTRINSIC_CHANNELS + MASK_CHANNELS + SHADING_CHANNELS
    if cond.shape[1] != full:
        raise ValueError(f"residual prior: cond has {cond.shape[1]} channels, a model with the shading prior has {full}")
    return cond[:, -SHADING_CHANNELS:]


def is_video_unet(unet: UNet2DConditionModel) -> bool:
    return int(unet.config.in_channels) not in (IMAGE_IN, IMAGE_IN_PRIOR)


def unet_inputs(x_t: torch.Tensor, cond: torch.Tensor, ref: torch.Tensor | None, in_channels: int) -> torch.Tensor:
    """(BN, 4, h, w) noisy latents + (BN, C_cond, h, w) conditioning + (BN, 4, h, w) references
    -> (BN, in_channels, h, w) in the UNet's input order. in_channels 23 (image UNet: reference,
    mask and shading are not inputs), 27 (image UNet with the shading prior), 28 or 32."""
    if x_t.shape[0] != cond.shape[0] or x_t.shape[-2:] != cond.shape[-2:]:
        raise ValueError(f"x_t {tuple(x_t.shape)} and cond {tuple(cond.shape)} disagree in frames or size")
    intrinsic = cond[:, :INTRINSIC_CHANNELS]  # (BN, 19, h, w)
    if in_channels == IMAGE_IN:
        return torch.cat([x_t, intrinsic], dim=1)  # (BN, 23, h, w)
    if in_channels == IMAGE_IN_PRIOR:
        if cond.shape[1] != INTRINSIC_CHANNELS + MASK_CHANNELS + SHADING_CHANNELS:
            raise ValueError(f"the image UNet takes the shading prior (27 inputs) but cond has {cond.shape[1]} channels, "
                             f"not {INTRINSIC_CHANNELS + MASK_CHANNELS + SHADING_CHANNELS} (shading prior on one side only?)")
        return torch.cat([x_t, intrinsic, cond[:, -SHADING_CHANNELS:]], dim=1)  # (BN, 27, h, w)
    rest = cond[:, INTRINSIC_CHANNELS:]  # (BN, 1 [+4], h, w): mask [, shading]
    expected = in_channels - LATENT - INTRINSIC_CHANNELS - REF_CHANNELS
    if rest.shape[1] != expected:
        raise ValueError(
            f"the UNet takes {in_channels} input channels, so cond needs {INTRINSIC_CHANNELS + expected} channels; "
            f"got {cond.shape[1]} (shading prior on one side only?)"
        )
    if ref is None:
        ref = x_t.new_zeros(x_t.shape)
    return torch.cat([x_t, intrinsic, ref.to(x_t.dtype), rest], dim=1)  # (BN, 28|32, h, w)


def run_unet(
    unet: UNet2DConditionModel,
    x_t: torch.Tensor,
    t: torch.Tensor | float | int,
    cond: torch.Tensor,
    ref: torch.Tensor | None,
    *,
    num_frames: int,
    text_global: torch.Tensor,
    ref_positions: Sequence[int] = (),
    mode: str = "key",
    level: int = 1,
    text_local: torch.Tensor | None = None,
    local_masks: torch.Tensor | None = None,
    prediction: str = "v",
) -> torch.Tensor:
    """v-prediction for B windows of N frames (window-major batch BN = B*N). Differentiable (training).
    `prediction` is what the UNet outputs (`ModelConfig.prediction`): "v", or "sample" (x0), which is
    converted to v here, so samplers and losses always see v.

    x_t, ref: (BN, 4, h, w); cond: (BN, C_cond, h, w); t: scalar or (B,) per window or (BN,);
    text_global: (B, L, D) or (1, L, D); text_local: (B, P, L, D) or None; local_masks:
    (BN, P, H, W) any resolution or None. All windows of one call share mode/level/ref_positions.
    An image UNet (23 inputs) runs every frame independently and ignores references and local prompts."""
    bn = x_t.shape[0]
    if bn % num_frames:
        raise ValueError(f"batch of {bn} latents is not a whole number of {num_frames}-frame windows")
    b = bn // num_frames
    t = torch.as_tensor(t, device=x_t.device)
    if t.ndim == 0:
        t = t.expand(bn)
    elif t.shape[0] == b and b != bn:
        t = t.repeat_interleave(num_frames)  # (BN,)
    elif t.shape[0] != bn:
        raise ValueError(f"t has {t.shape[0]} entries; expected 1, {b} (windows) or {bn} (frames)")
    if text_global.shape[0] not in (1, b):
        raise ValueError(f"text_global has {text_global.shape[0]} prompts for {b} windows")
    enc = text_global.to(x_t.dtype).repeat_interleave(num_frames, 0) if text_global.shape[0] == b else text_global.to(x_t.dtype).expand(bn, -1, -1)
    if prediction not in PREDICTIONS:
        raise ValueError(f"unknown prediction {prediction!r} (one of {', '.join(PREDICTIONS)})")
    in_channels = int(unet.config.in_channels)
    sample = unet_inputs(x_t, cond.to(x_t.dtype), ref, in_channels)
    if not is_video_unet(unet):
        out = unet(sample, t, encoder_hidden_states=enc).sample
        return v_from_sample(out, x_t, t) if prediction == "sample" else out
    if text_local is not None and text_local.shape[0] == 1 and b > 1:
        text_local = text_local.expand(b, -1, -1, -1)
    ctx = AttnContext(
        num_frames=num_frames,
        latent_size=(x_t.shape[-2], x_t.shape[-1]),
        ref_positions=tuple(ref_positions),
        mode=mode,
        level=level,
        text_local=None if text_local is None else text_local.to(x_t.dtype),
        local_masks=local_masks,
    )
    out = unet(sample, t, encoder_hidden_states=enc, cross_attention_kwargs={"x2v": ctx}).sample
    return v_from_sample(out, x_t, t) if prediction == "sample" else out
