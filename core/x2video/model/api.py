"""What the sampler and the `Renderer` need from a model: the contract between model/ and sampling/.

`x2video.model.pipeline.X2VideoModel` implements it with diffusers modules; tests may use
small fakes. Shapes: N frames of a window travel in the batch dimension.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, Sequence

import numpy as np
import torch

from x2video.conditioning.frame import FrameConditioning

if TYPE_CHECKING:
    from x2video.model.residual import ResidualNet


@dataclass
class WindowInputs:
    """Everything but the noisy latent that one UNet call over a window of N frames needs."""

    cond: torch.Tensor  # (N, C_cond, h, w) per-frame conditioning latents from `encode_frames`
    ref: torch.Tensor  # (N, 4, h, w) reference latents at `ref_positions`, zeros elsewhere
    ref_positions: tuple[int, ...]  # () no reference, (0,) keyframe mode, (0, N-1) interpolation
    mode: str  # "key" (keyframe prediction) or "interp" (interpolation)
    level: int  # recursive level k >= 1 (keyframe windows carry the top level K)
    text_global: torch.Tensor  # (1, L, D) global prompt token embeddings
    text_local: torch.Tensor  # (P, L, D) local prompt token embeddings, P >= 0
    local_masks: torch.Tensor  # (N, P, H, W) pixel-resolution masks of the local prompts


class RenderModel(Protocol):
    """A frozen model the sampler can drive. All tensors on `device`, dtype `dtype`."""

    device: torch.device
    dtype: torch.dtype
    #: latent downsampling factor of the VAE and latent channels of the output
    downsample: int
    latent_channels: int
    #: the diffusion schedule the model was trained with: betas over `num_train_timesteps`
    num_train_timesteps: int
    #: whether LCM (distilled) weights are loaded, so `sampler="lcm"` is allowed
    has_lcm: bool
    #: whether the sampler's output is a residual over the shading prior (see `sample_to_latents`, `detail`)
    residual_prior: bool
    #: what the shading-prior slot holds (`ModelConfig.prior`): "shading", or "tier1" (`FrameConditioning.prior`, tier 1's
    #: frame made with `residual_net`, which the conditioning set-up fills before `encode_frames`)
    prior: str
    #: channels of `encode_frames`' output (C_cond)
    cond_channels: int
    #: the tier-1 network (`x2video.model.residual`) the residual tier runs, or None (that tier is then unavailable)
    residual_net: ResidualNet | None
    #: whether quality 'auto' may render with `residual_net` (its record says it beat the formula); else auto keeps the formula
    residual_auto: bool
    #: tier 1's net fine-tuned for its difference over a shot's own frames (difference.safetensors beside residual.safetensors,
    #: `x2video train difference`), or None: the residual tier's difference over the base then runs `residual_net`
    difference_net: ResidualNet | None
    #: the prompt encoder, or None for a model that loads it on first `encode_prompts` (`prepare` warms it when set)
    text_encoder: Any

    def set_engine(self, engine: str) -> str:
        """Run the UNet, decoder and channel encoder on `engine` (`RenderSettings.engine`: 'auto', 'torch', 'onnx',
        'openvino'); returns what runs them ('torch' for a model without exported graphs)."""
        ...

    def alphas_cumprod(self) -> torch.Tensor:
        """(num_train_timesteps,) float64 cumulative alphas (zero-terminal-SNR rescaled)."""
        ...

    def content_key(self) -> str:
        """A string identifying the weights, for the conditioning-latent cache."""
        ...

    def encode_frames(self, frames: Sequence[FrameConditioning]) -> torch.Tensor:
        """(N, C_cond, h, w): VAE latents of albedo/normal/roughness/metallic, downsampled
        irradiance, shading prior (if the config has it) and the A|M|R union mask. Pure in its
        input, so the Renderer caches it per frame by content."""
        ...

    def encode_image(self, rgb_linear: np.ndarray) -> torch.Tensor:
        """(4, h, w) latent of an (H, W, 3) linear RGB image (reference frames)."""
        ...

    def encode_prompts(self, prompts: Sequence[str]) -> torch.Tensor:
        """(P, L, D) token embeddings; P = len(prompts) (0 gives (0, L, D))."""
        ...

    def predict_v(self, x_t: torch.Tensor, t: torch.Tensor, window: WindowInputs, *, lcm: bool = False) -> torch.Tensor:
        """v-prediction for a window: x_t (N, 4, h, w), t scalar timestep -> (N, 4, h, w)."""
        ...

    def sample_to_latents(self, x0: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """(N, 4, h, w) RGB latents from a window's sample and its (N, C_cond, h, w) conditioning
        (identity unless the model samples a residual over a prior)."""
        ...

    def detail(self, frames: Sequence[FrameConditioning], cond: torch.Tensor) -> np.ndarray | None:
        """(N, H, W, 3) linear detail to add to the decoded frames of `frames`, or None."""
        ...

    def decode(self, latents: torch.Tensor) -> np.ndarray:
        """(N, 4, h, w) latents -> (N, H, W, 3) linear RGB float32."""
        ...
