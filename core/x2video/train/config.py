"""Training settings without the training code (no torch): the optimisation loop, conditioning augmentation,
video windows and each stage's own settings (vae, image, video, lcm, encoder; the stage modules re-export
theirs). Field docstrings are the help of `x2video train`'s flags, generated from these fields
(`x2video.fields.add_fields`), so building the command line imports no torch."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    from x2video.model.config import ModelConfig


@dataclass
class LoopConfig:
    """Optimisation settings shared by every stage (field docstrings are CLI help)."""

    steps: int = 1000
    """Total optimiser steps (a resumed run continues up to this number)."""
    lr: float = 1e-4
    """Peak AdamW learning rate (after linear warm-up)."""
    warmup: int = 50
    """Linear warm-up steps."""
    lr_half_every: int = 0
    """Halve the learning rate every this many steps (paper: 20,000); 0 = constant."""
    weight_decay: float = 0.0
    """AdamW weight decay."""
    grad_clip: float = 1.0
    """Clip the gradients' norm to this; 0 = no clipping."""
    ema_decay: float = 0.999
    """EMA decay of the weights that get saved for inference; 0 disables EMA."""
    ckpt_every: int = 500
    """Write a resumable `step-XXXXXXXXX/` checkpoint every this many steps (and at the end)."""
    keep_ckpts: int = 2
    """How many step checkpoints to keep on disk."""
    time_limit_s: float = 0.0
    """Stop (with a checkpoint) after this many seconds of training; 0 = no limit."""
    seed: int = 0
    """Seed of the weights' initialisation and of the batches drawn."""
    mixed_precision: Literal["no", "fp16", "bf16"] = "no"
    """accelerate mixed precision (GPU)."""
    workers: int = 0
    """Processes drawing batches ahead of the optimiser (0: drawn in the training process). Not
    part of what a run is: a run resumes with any number, with fresh batches either way."""


@dataclass
class AugmentConfig:
    """Conditioning augmentation (field docstrings are CLI help)."""

    channel_drop_p: float = 0.5
    """Probability of dropping each intrinsic channel (XRGB / paper: 0.5)."""
    prompt_drop_p: float = 0.3
    """Probability the global prompt is "" instead of the room's caption."""
    mask_p: float = 0.5
    """Probability a sample has A|M|R-masked objects (then 1..max_masks of them)."""
    max_masks: int = 5
    """Most masked objects (local prompts) per sample."""
    local_prompt_p: float = 0.8
    """Probability a masked object carries its caption as a local prompt."""
    min_object_frac: float = 0.01
    """Objects covering less of the first frame than this are not picked for masks."""
    ref_shift_p: float = 0.0
    """Probability a window with references has its target and its references shifted alike by a random
    latent offset per object (and one for the whole window), so that what the references show beyond
    the channels is what the other frames must show too (`object_shift`); 0: off. Windows without
    references are never shifted."""
    ref_shift_std: float = 0.3
    """Largest standard deviation of those offsets, as a fraction of each RGB latent channel's standard
    deviation over the split (each window draws its own fraction in [0, this])."""


@dataclass
class WindowConfig:
    """How video windows are drawn (paper Sec. Recursive Sampling / Implementation: N=5, K=3)."""

    frames: int = 5
    """N: frames per window."""
    levels: int = 3
    """K: keyframe windows use stride (N-1)^(k-1) for k in 1..K; interpolation levels 1..K."""
    interp_p: float = 0.5
    """Probability a batch is interpolation-mode windows (else keyframe-mode)."""
    ref_p_key: float = 0.5
    """Probability keyframe windows carry the start frame as reference."""
    ref_p_interp: float = 0.5
    """Probability interpolation windows carry the start and end frames as references."""
    reverse_p: float = 0.5
    """Probability the windows run backwards in time (the planner's backward keyframe windows)."""
    short_p: float = 0.1
    """Probability of a shorter window (the planner's tail windows), 2..N-1 frames (3.. interpolating)."""


@dataclass
class CacheStageConfig:
    """What the cache stage encodes with the frozen VAE (field docstrings are CLI help)."""

    size: tuple[int, int] | None = None
    """(width, height) frames are resized to before encoding (e.g. 160x112, the diffusion training size); None: native."""
    prior: Literal["shading", "tier1"] = "shading"
    """What the prior latents hold: the classical shading, or tier 1's frames (for a model sampling its residual over
    tier 1: the image, video and LCM stages take the prior of their cache)."""
    residual: str | None = None
    """With --prior tier1: the folder whose residual.safetensors makes tier 1's frames (default: the shipped weights)."""
    batch: int = 8
    """Frames per VAE call."""


@dataclass
class VAEStageConfig:
    """What the VAE stage trains and on what (field docstrings are CLI help)."""

    preset: str = "tiny"
    """Model preset whose VAE sizes are the default (tiny: f=8)."""
    vae_channels: tuple[int, ...] | None = None
    """VAE block widths, e.g. (32, 64, 128): latent factor f = 2**(len-1). None: the preset's."""
    layers_per_block: int | None = None
    """ResNet layers per VAE block. None: the preset's."""
    size: tuple[int, int] | None = None
    """(width, height) frames are resized to before cropping (the diffusion training size); None: native."""
    crop: int = 64
    """Square crop side in pixels (a multiple of f)."""
    batch: int = 16
    """Crops per batch."""
    kl_weight: float = 1e-6
    """Weight of the KL term per pixel (SD's autoencoder: 1e-6)."""
    pool_frames_per_room: int = 16
    """Frames per training room held in memory (evenly spaced)."""
    eval_frames_per_room: int = 2
    """Held-out frames per test room for the PSNR report."""
    seed: int = 0

    def model_config(self) -> ModelConfig:
        from x2video.model.config import VAEConfig, preset

        base = preset(self.preset)
        v = base.vae
        widths = tuple(self.vae_channels) if self.vae_channels else v.block_out_channels
        groups = math.gcd(v.norm_num_groups, *widths)
        vae = VAEConfig(block_out_channels=widths, layers_per_block=self.layers_per_block or v.layers_per_block,
                        latent_channels=v.latent_channels, norm_num_groups=groups)
        return dataclasses.replace(base, vae=vae)


@dataclass
class EncoderStageConfig:
    """What the encoder stage trains and on what (field docstrings are CLI help)."""

    batch: int = 16
    """Whole-frame images per batch."""
    size: tuple[int, int] | None = None
    """(width, height) frames are resized to (the teacher's training size); None: native."""
    pool_frames_per_room: int = 16
    """Frames per training room held in memory (evenly spaced); five to six images each."""
    eval_frames_per_room: int = 8
    """Held-out frames per test room for the error report."""
    seed: int = 0


@dataclass
class LCMStageConfig:
    """LCM distillation (field docstrings are CLI help)."""

    batch: int = 2
    """Windows per batch."""
    ddim_steps: int = 50
    """Teacher DDIM grid (skipping interval 1000 / ddim_steps); must match LCMScheduler's original_inference_steps (50)."""
    target_ema: float = 0.95
    """EMA decay of the target network theta- (LCM: 0.95)."""
    huber_c: float = 0.001
    """Pseudo-Huber constant (LCM-LoRA training script: 0.001)."""
    noise_shared: float = 0.0
    """Fraction of the noise's variance a window's frames share, in [0, 1]: distil with the mixed noise prior
    the Renderer samples with by default (`RenderSettings.noise_shared`), as `x2video train video
    --noise-shared` trains the teacher; 0: independent per frame, as the shipped LCM UNet was distilled."""
    seed: int = 0
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    window: WindowConfig = field(default_factory=WindowConfig)


@dataclass
class ImageStageConfig:
    """The image stage (field docstrings are CLI help)."""

    preset: str = "tiny"
    """Model preset of the UNet (tiny: 32/64/128 channels)."""
    unet_channels: tuple[int, ...] | None = None
    """UNet block widths overriding the preset's (attention on all but the first level)."""
    shading_prior: bool = True
    """Feed the classical shading latent (our addition); the paper's layout is off."""
    residual_prior: bool = True
    """With the shading prior: learn the residual over the prior's latent (ignored without the prior)."""
    init: str | None = None
    """Start from this image model (a run or model folder of the same architecture) instead of random weights."""
    prediction: Literal["v", "sample"] | None = None
    """What the UNet outputs: "v" or "sample" (x0). None: "sample" for a residual model, else "v". A
    "sample" head that is new (fresh weights, or an --init trained for v) starts at zero."""
    batch: int = 16
    """Frames per batch."""
    seed: int = 0
    heldout_batches: int = 4
    """Batches of held-out (test) frames for the final held-out v-loss (0: skip)."""
    augment: AugmentConfig = field(default_factory=AugmentConfig)


@dataclass
class VideoStageConfig:
    """The video stage (field docstrings are CLI help)."""

    batch: int = 2
    """Windows per batch (each of `window.frames` frames)."""
    shading_prior: bool | None = None
    """Feed the classical shading latent; None: as the image model was trained."""
    residual_prior: bool | None = None
    """Learn the residual over the shading prior's latent; None: as the --init model was trained; True continues an
    absolute-target model as a residual one."""
    prediction: Literal["v", "sample"] | None = None
    """None: as the --init model; "sample" continues a v model with a zero-initialised x0 head."""
    alpha_lr_mult: float = 100.0
    """Learning-rate multiplier of the Hybrid Self-Attention alphas. They start at 0 and are single
    scalars, so at the UNet's rate Adam moves each by at most ~lr per step: after 2,458 steps at
    <= 1e-4 they sat at 0.01-0.05 and the reference and temporal branches were nearly off."""
    train_only: Literal["all", "interp"] = "all"
    """"all": every parameter trains. "interp": only the interpolation-mode LoRA branches (the temporal
    branches interp1..K and the end-frame reference branch r1) of a video --init; everything keyframe-mode
    and sequential windows use (the UNet, the alphas, the "key" and "r0" branches) stays bit-identical; needs
    `window.interp_p` 1 (--interp-p 1)."""
    noise_shared: float = 0.0
    """Fraction of the noise's variance the frames of a training window share (the mixed noise prior
    the Renderer samples with by default, `RenderSettings.noise_shared`); 0: independent per frame, as
    the shipped weights were trained. The held-out v-loss uses the same noise."""
    seed: int = 0
    heldout_batches: int = 4
    """Batches of held-out (test) windows for the final held-out v-loss (0: skip)."""
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    window: WindowConfig = field(default_factory=WindowConfig)
