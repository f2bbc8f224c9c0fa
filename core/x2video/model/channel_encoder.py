"""The distilled channel encoder: the VAE's encoder without its mid-block self-attention, fine-tuned to
give the latents the full encoder gives, for the conditioning channels (albedo, normal, roughness,
metallic, the shading prior).

Encoding those channels is four or five VAE-encoder passes per frame, the same work for every
sampler: the fixed cost per frame that bounds LCM-2's speed-up over DDIM-20 (table d).
A third of the encoder's time goes to the mid-block self-attention over every latent position
(1,120 at 160x112). diffusers builds the same encoder without it (`mid_block_add_attention=False`);
started from the VAE's own weights and trained to reproduce the full encoder's posterior mode
(`x2video train encoder`), it stands in for the encoder on the conditioning channels, and the UNet
is not retrained: it sees approximately the latents it was trained on. The reference frame, the
decoder and the training latents keep the full VAE. A model uses it only when its folder ships
`channel_encoder.safetensors` and the caller asks for it (`--channel-encoder`).

Its tensors have the VAE's names (`encoder.*`, `quant_conv.*`), less the attention's, and its sizes
are the model config's VAE sizes.
"""
from __future__ import annotations

import torch
from diffusers import AutoencoderKL
from torch import nn

from x2video.model.config import VAEConfig
from x2video.model.vae import build_vae


class ChannelEncoder(nn.Module):
    """(N, 3, H, W) images in [-1, 1] -> (N, latent_channels, H/f, W/f) unscaled posterior mode, like
    `encode_mode(vae, x)`, from the VAE's encoder built without the mid-block attention."""

    def __init__(self, cfg: VAEConfig) -> None:
        super().__init__()
        vae = build_vae(cfg, mid_attention=False)
        self.encoder, self.quant_conv = vae.encoder, vae.quant_conv  # the decoder is not needed
        self.latent_channels = cfg.latent_channels
        self.factor = cfg.downsample

    @classmethod
    def from_vae(cls, vae: AutoencoderKL, cfg: VAEConfig) -> "ChannelEncoder":
        """The student before training: the VAE's own encoder weights, the attention left out."""
        enc = cls(cfg)
        own = enc.state_dict()
        src = vae.state_dict()
        missing = sorted(k for k in own if k not in src)
        if missing:
            raise ValueError(f"the VAE lacks encoder tensors {missing[:4]}; its config does not match {cfg}")
        enc.load_state_dict({k: src[k].detach().clone().float() for k in own})
        return enc

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1] != 3:
            raise ValueError(f"ChannelEncoder: expected (N, 3, H, W) images, got {tuple(x.shape)}")
        if x.shape[2] % self.factor or x.shape[3] % self.factor:
            raise ValueError(f"ChannelEncoder: size {x.shape[2]}x{x.shape[3]} is not a multiple of {self.factor}")
        moments = self.quant_conv(self.encoder(x))  # (N, 2 * latent, h, w): mean, log-variance
        return moments[:, : self.latent_channels]  # the posterior's mode is its mean
