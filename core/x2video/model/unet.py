"""UNet builders: the XRGB image UNet (23 inputs) and its conversion to the X2Video video UNet (28/32 inputs).

Input layout (docs/ARCHITECTURE.md "The model"; XRGB release order, extended):

    [noisy 4 | albedo 4 | normal 4 | roughness 4 | metallic 4 | irradiance 3 | reference R 4 | union mask 1 | shading 4]
     \\________________________ image UNet: 23 _______________________/ \\__ video: 28 __________/ \\ +prior: 32 /

The conversion copies the image UNet, zero-initialises the new input channels, puts a
`HybridSelfAttnProcessor` (alphas 0) on every `attn1` and a `MaskedCrossAttnProcessor` on
every `attn2`, so the video UNet computes exactly what the image UNet computes per frame.
"""
from __future__ import annotations

import copy

import torch
from diffusers import UNet2DConditionModel
from diffusers.models.attention_processor import Attention, AttnProcessor2_0
from torch import nn

from x2video.model.config import HybridConfig, ModelConfig, UNetConfig
from x2video.model.cross_attention import MaskedCrossAttnProcessor
from x2video.model.hybrid_attention import HybridSelfAttnProcessor

LATENT = 4
#: conditioning channels of the image layout: albedo, normal, roughness, metallic (VAE, 4 each) + irradiance (3)
INTRINSIC_CHANNELS = 4 * 4 + 3
IMAGE_IN = LATENT + INTRINSIC_CHANNELS  # 23
REF_CHANNELS = 4
MASK_CHANNELS = 1
SHADING_CHANNELS = 4
VIDEO_IN = IMAGE_IN + REF_CHANNELS + MASK_CHANNELS  # 28
IMAGE_IN_PRIOR = IMAGE_IN + SHADING_CHANNELS  # 27: our image UNet with the shading prior appended


def image_in_channels(shading_prior: bool) -> int:
    """23 (XRGB layout) or 27 (with the shading prior appended)."""
    return IMAGE_IN + (SHADING_CHANNELS if shading_prior else 0)


def video_in_channels(shading_prior: bool) -> int:
    """28 (paper layout) or 32 (with the shading prior appended)."""
    return VIDEO_IN + (SHADING_CHANNELS if shading_prior else 0)


def build_image_unet(cfg: UNetConfig, sample_size: int = 64, shading_prior: bool = False) -> UNet2DConditionModel:
    """A freshly initialised XRGB-layout image UNet (23 inputs, or 27 with the shading prior
    appended; 4 outputs, v-prediction by training)."""
    down = tuple("CrossAttnDownBlock2D" if a else "DownBlock2D" for a in cfg.attention_levels)
    up = tuple("CrossAttnUpBlock2D" if a else "UpBlock2D" for a in reversed(cfg.attention_levels))
    unet = UNet2DConditionModel(
        sample_size=sample_size,
        in_channels=image_in_channels(shading_prior),
        out_channels=LATENT,
        down_block_types=down,
        up_block_types=up,
        block_out_channels=cfg.block_out_channels,
        layers_per_block=cfg.layers_per_block,
        attention_head_dim=cfg.attention_heads,  # diffusers' name for the number of heads
        cross_attention_dim=cfg.cross_attention_dim,
        norm_num_groups=cfg.norm_num_groups,
        use_linear_projection=cfg.use_linear_projection,
        upcast_attention=cfg.upcast_attention,
        transformer_layers_per_block=cfg.transformer_layers_per_block,
    )
    unet.set_attn_processor(AttnProcessor2_0())
    return unet


def _widen_conv_in(unet: UNet2DConditionModel, in_channels: int) -> None:
    """Replace conv_in by one with `in_channels` inputs: old weights first, new input channels zero."""
    old = unet.conv_in
    if in_channels < old.in_channels:
        raise ValueError(f"cannot narrow conv_in from {old.in_channels} to {in_channels} channels")
    new = nn.Conv2d(in_channels, old.out_channels, old.kernel_size, old.stride, old.padding)
    new = new.to(device=old.weight.device, dtype=old.weight.dtype)
    with torch.no_grad():
        new.weight.zero_()
        new.weight[:, : old.in_channels] = old.weight
        new.bias.copy_(old.bias)
    unet.conv_in = new
    unet.register_to_config(in_channels=in_channels)


def install_video_processors(unet: UNet2DConditionModel, hybrid: HybridConfig) -> None:
    """Hybrid Self-Attention on every attn1 (weights copied from it), Masked Cross-Attention on every attn2."""
    procs: dict[str, nn.Module] = {}
    modules = dict(unet.named_modules())
    for name in unet.attn_processors:  # e.g. "down_blocks.1.attentions.0.transformer_blocks.0.attn1.processor"
        attn = modules[name.removesuffix(".processor")]
        assert isinstance(attn, Attention)
        if name.endswith("attn1.processor"):
            procs[name] = HybridSelfAttnProcessor(attn, hybrid)
        elif name.endswith("attn2.processor"):
            procs[name] = MaskedCrossAttnProcessor()
        else:
            raise ValueError(f"unexpected attention layer {name} in the UNet")
    unet.set_attn_processor(procs)


def convert_image_to_video(image_unet: UNet2DConditionModel, hybrid: HybridConfig, shading_prior: bool) -> UNet2DConditionModel:
    """A new video UNet from an XRGB image UNet (the input is left untouched).

    New input channels (reference 4, mask 1, and shading 4 unless the image UNet already had
    them) start at zero; a 27-channel image UNet's shading weights move behind reference and
    mask. Reference/temporal projections start as copies of each self-attention's q/k/v;
    a_r = a_t = 0 and LoRA `up` weights are zero, so the output equals the image UNet's on every frame."""
    cin = int(image_unet.config.in_channels)
    if cin not in (IMAGE_IN, IMAGE_IN_PRIOR):
        raise ValueError(f"expected an image UNet with {IMAGE_IN} (or {IMAGE_IN_PRIOR}, shading prior) input channels, got {cin}")
    if cin == IMAGE_IN_PRIOR and not shading_prior:
        raise ValueError("this image UNet was trained with the shading prior (27 inputs); convert it with the shading prior on")
    unet = copy.deepcopy(image_unet)
    _widen_conv_in(unet, video_in_channels(shading_prior))
    if cin == IMAGE_IN_PRIOR:  # [x 4 | intrinsic 19 | shading 4] -> [x 4 | intrinsic 19 | ref 4 | mask 1 | shading 4]
        with torch.no_grad():
            w = unet.conv_in.weight
            w[:, VIDEO_IN:] = w[:, IMAGE_IN:IMAGE_IN_PRIOR].clone()
            w[:, IMAGE_IN:VIDEO_IN] = 0
    install_video_processors(unet, hybrid)
    return unet


def build_unet(cfg: ModelConfig) -> UNet2DConditionModel:
    """The UNet a config describes, freshly initialised: image (23/27) or converted video (28/32)."""
    image = build_image_unet(cfg.unet, shading_prior=cfg.shading_prior and not cfg.video)
    if not cfg.video:
        return image
    return convert_image_to_video(image, cfg.hybrid, cfg.shading_prior)


def hybrid_processors(unet: UNet2DConditionModel) -> dict[str, HybridSelfAttnProcessor]:
    """The Hybrid Self-Attention processors of a video UNet by layer name (for alphas, LoRA, tests)."""
    return {k: p for k, p in unet.attn_processors.items() if isinstance(p, HybridSelfAttnProcessor)}
