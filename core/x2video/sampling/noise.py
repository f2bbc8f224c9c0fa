"""A diffusion window's noise and its lighting anchor: seeded per window or per shot frame (`RenderSettings.noise`),
and `mean_anchor`, the sampler's `denoised_fn` that keeps an inferred region's latent mean between its references'
(`RenderSettings.ref_dc`). Pure functions of the seed, the window and the frames' conditioning."""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import torch

from x2video.conditioning.frame import FrameConditioning
from x2video.model.shading import shading_available
from x2video.sampling.planner import Window
from x2video.sampling.samplers import mix_noise


def window_seed(seed: int, window: Window) -> int:
    """Seed of one window's initial noise: depends on the user seed and the window's frames and level only."""
    return int(np.random.SeedSequence([seed, window.level, *window.frames]).generate_state(1, np.uint64)[0] >> 1)


def _seeded(*entropy: int) -> torch.Generator:
    return torch.Generator(device="cpu").manual_seed(int(np.random.SeedSequence(list(entropy)).generate_state(1, np.uint64)[0] >> 1))


def frame_noise(seed: int, frames: Sequence[int], shape: tuple[int, ...], shared: float = 0.0, draw: int = 0) -> torch.Tensor:
    """(len(frames), *shape) CPU float32 noise, one draw per shot frame (`RenderSettings.noise` =
    'frame'): frame f's noise depends only on the seed, f, `draw` (0: the initial noise; i: what LCM
    adds back after step i) and `shared`, the fraction of variance every frame shares:
    sqrt(shared) e + sqrt(1 - shared) e_f with e and e_f independent N(0, I)."""
    x = torch.stack([torch.randn(*shape, generator=_seeded(seed, 1, draw, f)) for f in frames])
    return mix_noise(x, torch.randn(*shape, generator=_seeded(seed, 2, draw)), shared) if shared > 0.0 else x


def inferred_region(cond: FrameConditioning, size: tuple[int, int]) -> torch.Tensor:
    """(h, w) weights in [0, 1] of where a frame's lighting must be inferred, at latent size (h, w):
    everywhere without albedo or irradiance (no classical shading), else the A|M|R mask, area-averaged."""
    if not shading_available(cond.channels):
        return torch.ones(size)
    m = torch.from_numpy(np.asarray(cond.amr_mask, np.float32))[None, None]  # (1, 1, H, W)
    return torch.nn.functional.adaptive_avg_pool2d(m, size)[0, 0]


def region_mean(z: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(..., 4) weighted mean per channel of latents z (..., 4, h, w) over region weights w (..., h, w)."""
    w = w.to(z.device, torch.float32)[..., None, :, :]
    return (z.float() * w).sum(dim=(-2, -1)) / w.sum(dim=(-2, -1))


def anchor_positions(window: Window, strength: float,
                     regions: Sequence[torch.Tensor]) -> tuple[int, int, list[int]] | None:
    """Where `mean_anchor` acts in a window: (p0, p1, gen), the positions of its two references and of
    the generated frames with an inferred region (`regions[p]`, (h, w) weights); None unless the window
    interpolates between two references, strength > 0 and some frame of it has such a region (less
    than one latent pixel counts as none)."""
    if strength <= 0 or window.mode != "interp" or len(window.refs) != 2:
        return None
    p0, p1 = (window.frames.index(f) for f in window.refs)
    if min(float(regions[p0].sum()), float(regions[p1].sum())) < 1.0:
        return None
    gen = [p for p in window.generate_positions if float(regions[p].sum()) >= 1.0]
    return (p0, p1, gen) if gen else None


def mean_anchor(window: Window, strength: float, ref: torch.Tensor, offset: torch.Tensor,
                regions: Sequence[torch.Tensor]) -> Callable[[torch.Tensor, int], torch.Tensor] | None:
    """`RenderSettings.ref_dc` for one window: a sampler's `denoised_fn` that moves the clean estimate
    of each generated frame inside the region where its lighting must be inferred (`regions[p]`, (h, w)
    weights, `inferred_region`) so that the region's RGB latent mean per channel goes `strength` of
    the way to the linear interpolation, by window position, of the two references' means over their
    own regions; None where `anchor_positions` finds nothing to anchor.

    ref: (n, 4, h, w) the window's reference RGB latents; offset: (n, 4, h, w) what
    `sample_to_latents` adds to a sample at each position (the shading prior's latent, or 0)."""
    where = anchor_positions(window, strength, regions)
    if where is None:
        return None
    p0, p1, gen = where
    w_gen = torch.stack([regions[p] for p in gen])  # (G, h, w)
    m0, m1 = region_mean(ref[p0], regions[p0]), region_mean(ref[p1], regions[p1])  # (4,)
    lam = torch.tensor([(p - p0) / (p1 - p0) for p in gen], device=ref.device)[:, None]  # (G, 1)
    target = (1 - lam) * m0 + lam * m1  # (G, 4)

    def anchor(x0: torch.Tensor, i: int) -> torch.Tensor:
        x0 = x0.clone()
        now = region_mean(x0[gen] + offset[gen], w_gen)  # (G, 4)
        shift = strength * (target - now)[..., None, None] * w_gen.to(x0.device)[:, None]  # (G, 4, h, w)
        x0[gen] += shift.to(x0.dtype)
        return x0

    return anchor
