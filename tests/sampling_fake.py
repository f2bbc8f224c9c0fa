"""A small deterministic `RenderModel` for sampler/renderer tests (no weights, no diffusers UNet).

Its v-prediction is the exact v of a target x0 that depends on the frame's conditioning, the
reference latents at the window's reference positions, the global prompt and (weakly) the
noisy input, so seeds, references, prompts and conditioning all change the output.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from x2video.conditioning.frame import FrameConditioning
from x2video.model.api import WindowInputs
from x2video.sampling.samplers import alphas_cumprod
from x2video.shot import ArrayShot


class FakeModel:
    device = torch.device("cpu")
    dtype = torch.float32
    downsample = 8
    latent_channels = 4
    num_train_timesteps = 1000
    residual_prior = False
    prior = "shading"
    residual_net = None  # no tier-1 network: quality auto renders with the sampler
    difference_net = None  # no difference net: tier 1's difference over a base runs residual_net
    residual_auto = True
    text_encoder = None

    @property
    def cond_channels(self) -> int:
        return self.latent_channels

    def set_engine(self, engine: str) -> str:
        return "torch"  # no exported graphs

    def __init__(self, has_lcm: bool = False, key: str = "fake-v1") -> None:
        self.has_lcm = has_lcm
        self._key = key
        self._ac = alphas_cumprod().float()
        self.encoded_frames = 0  # frames passed to encode_frames
        self.encoded_prompts: list[str] = []
        self.predict_calls = 0
        self.windows: list[WindowInputs] = []  # one per predict_v call
        self.x_t: list[tuple[int, torch.Tensor]] = []  # (t, noisy sample) per predict_v call
        self.decoded: list[torch.Tensor] = []  # (G, 4, h, w) per decode call
        self.on_predict = None  # optional hook(call_number)

    def alphas_cumprod(self) -> torch.Tensor:
        return alphas_cumprod()

    def content_key(self) -> str:
        return self._key

    def encode_frames(self, frames: Sequence[FrameConditioning]) -> torch.Tensor:
        self.encoded_frames += len(frames)
        out = []
        for c in frames:
            a = c.channels["albedo"]
            a = np.zeros((*c.size, 3), np.float32) if a is None else a
            x = torch.from_numpy(np.concatenate([a, c.amr_mask[..., None]], -1)).permute(2, 0, 1)[None]  # (1, 4, H, W)
            out.append(F.avg_pool2d(x, self.downsample)[0])  # (4, h, w)
        return torch.stack(out)  # (N, 4, h, w)

    def encode_image(self, rgb_linear: np.ndarray) -> torch.Tensor:
        x = torch.from_numpy(np.asarray(rgb_linear, np.float32)).permute(2, 0, 1)[None]  # (1, 3, H, W)
        x = F.avg_pool2d(x, self.downsample)[0]  # (3, h, w)
        return torch.cat([x, torch.ones_like(x[:1])])  # (4, h, w)

    def encode_prompts(self, prompts: Sequence[str]) -> torch.Tensor:
        self.encoded_prompts.extend(prompts)
        vals = [float(sum(map(ord, p)) % 97) / 97.0 for p in prompts]
        return torch.tensor(vals, dtype=torch.float32).reshape(len(prompts), 1, 1).expand(len(prompts), 2, 3).clone()

    def predict_v(self, x_t: torch.Tensor, t: torch.Tensor, window: WindowInputs, *, lcm: bool = False) -> torch.Tensor:
        self.predict_calls += 1
        self.windows.append(window)
        self.x_t.append((int(t), x_t.clone()))
        if self.on_predict is not None:
            self.on_predict(self.predict_calls)
        target = window.cond * 2 - 1 + window.text_global.mean()  # (N, 4, h, w)
        if window.ref_positions:
            target = target + 0.5 * window.ref[list(window.ref_positions)].mean(0, keepdim=True)
        target = target + 0.1 * torch.tanh(x_t)
        a = self._ac[int(t)]
        return (a.sqrt() * x_t - target) / (1 - a).sqrt()  # exact v of `target`

    def sample_to_latents(self, x0: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        return x0

    def detail(self, frames: Sequence[FrameConditioning], cond: torch.Tensor) -> np.ndarray | None:
        return None

    def decode(self, latents: torch.Tensor) -> np.ndarray:
        self.decoded.append(latents.clone())
        rgb = torch.sigmoid(latents[:, :3])  # (N, 3, h, w)
        rgb = F.interpolate(rgb, scale_factor=self.downsample, mode="nearest")  # (N, 3, H, W)
        return rgb.permute(0, 2, 3, 1).numpy().astype(np.float32)


def make_shot(num_frames: int = 9, height: int = 16, width: int = 24, seed: int = 0, irradiance: bool = True) -> ArrayShot:
    """A tiny shot whose albedo differs per frame (without an irradiance channel if not `irradiance`)."""
    rng = np.random.default_rng(seed)
    albedo = rng.uniform(0, 1, (num_frames, height, width, 3)).astype(np.float32)
    irr = np.ones((num_frames, height, width, 3), np.float32)
    normal = np.zeros((num_frames, height, width, 3), np.float32)
    normal[..., 2] = 1
    channels = {"albedo": albedo, "irradiance": irr, "normal": normal}
    if not irradiance:
        del channels["irradiance"]
    return ArrayShot(channels, fps=10.0)
