"""DDIM and LCM multistep samplers (paper Sec. Implementation: DDIM-20, LCM-2 after distillation).

Plain functions in the k-diffusion style around diffusers' schedulers: the schedule is
SD 2.1's scaled-linear betas (0.00085 to 0.012 over 1,000 steps) rescaled to zero terminal
SNR, v-prediction, "trailing" timestep spacing, as the XRGB release samples. With zero
terminal SNR the first step is at t=999 where alpha_cumprod = 0: the noisy latent carries no
signal and v-prediction gives x0 = -v there (epsilon-prediction would divide by zero).

`model_fn(x_t, t) -> v` gets x_t (N, C, h, w) and the timestep as a 0-d long tensor.
Every sampler reports each step through `callback({'x', 'i', 't', 'denoised', 'steps'})`
('x' is the sample after step i, 'denoised' the model's x0 estimate at step i) and checks
the cancel token before every step, raising `Cancelled`. Both take an optional `Known`:
reference positions held at the noised reference latent between steps
(`RenderSettings.replace_refs`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import torch
from diffusers import DDIMScheduler, LCMScheduler

from x2video.conditioning.frame import FrameConditioning
from x2video.model.shading import shading_available
from x2video.render.events import Cancelled, CancelToken
from x2video.sampling.planner import Window

ModelFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
StepCallback = Callable[[dict[str, Any]], None]


@dataclass(frozen=True)
class Known:
    """Window positions whose clean latent is known (reference frames produced by earlier windows).

    After every step but the last, the sample at `positions` is replaced by `x0` noised to the
    next step's level with the fixed noise `eps`, sqrt(a) x0 + sqrt(1 - a) eps: what the
    network saw at reference positions in training (the noised ground truth of that frame),
    instead of its own drifting estimate of a frame it does not produce.
    """

    positions: tuple[int, ...]
    x0: torch.Tensor  # (len(positions), C, h, w)
    eps: torch.Tensor  # (len(positions), C, h, w)

    def after_step(self, x: torch.Tensor, sched: DDIMScheduler | LCMScheduler, i: int) -> torch.Tensor:
        """`x` after step `i` of `sched`'s timesteps, with the known positions reset to the next
        step's level; the last step's output is returned as is."""
        if not self.positions or i >= len(sched.timesteps) - 1:
            return x
        return self.at_level(x, sched.alphas_cumprod[int(sched.timesteps[i + 1])])

    def at_level(self, x: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """`x` with the known positions set to their latent noised to alpha_cumprod `a`."""
        a = a.to(x.device, torch.float32)
        x = x.clone()
        x[list(self.positions)] = (a.sqrt() * self.x0.float() + (1 - a).sqrt() * self.eps.float()).to(x.dtype)
        return x

#: The diffusion schedule the model is trained with (docs/ARCHITECTURE.md "The model": SD 2.1 betas, zero-terminal SNR).
SCHEDULE: dict[str, Any] = dict(
    num_train_timesteps=1000,
    beta_start=0.00085,
    beta_end=0.012,
    beta_schedule="scaled_linear",
    prediction_type="v_prediction",
    rescale_betas_zero_snr=True,
    timestep_spacing="trailing",
    clip_sample=False,
    set_alpha_to_one=True,
)


def mix_noise(own: torch.Tensor, common: torch.Tensor, shared: float) -> torch.Tensor:
    """sqrt(shared) common + sqrt(1 - shared) own: standard normal again when both are, with a fraction
    `shared` of the variance common to every sample `common` broadcasts over (the mixed noise prior of
    Ge et al. 2023; the Renderer's per-frame noise and `x2video train video --noise-shared`)."""
    if not 0.0 <= shared <= 1.0:
        raise ValueError(f"noise_shared must lie in [0, 1], got {shared}")
    return math.sqrt(shared) * common + math.sqrt(1.0 - shared) * own


def ddim_scheduler(**overrides: Any) -> DDIMScheduler:
    """The project's DDIM scheduler (eta = 0, deterministic)."""
    return DDIMScheduler(**{**SCHEDULE, **overrides})


def lcm_scheduler(**overrides: Any) -> LCMScheduler:
    """The project's LCM scheduler: same betas, LCM's 50-step distillation grid (t = 999, 979, ...)."""
    cfg = {k: v for k, v in SCHEDULE.items() if k != "timestep_spacing"}
    return LCMScheduler(**{**cfg, **overrides})


def alphas_cumprod() -> torch.Tensor:
    """(1000,) float64 cumulative alphas of `SCHEDULE` (what a model trained with it reports)."""
    return ddim_scheduler().alphas_cumprod.to(torch.float64)


def _check_cancel(cancel: CancelToken | None, i: int) -> None:
    if cancel is not None and cancel.cancelled:
        raise Cancelled(f"cancelled before denoising step {i + 1}")


@torch.no_grad()
def sample_ddim(
    model_fn: ModelFn,
    x_T: torch.Tensor,
    steps: int,
    *,
    callback: StepCallback | None = None,
    cancel: CancelToken | None = None,
    scheduler: DDIMScheduler | None = None,
    known: Known | None = None,
    resample: int = 1,
    jump_noise: Callable[[int, int], torch.Tensor] | None = None,
    denoised_fn: Callable[[torch.Tensor, int], torch.Tensor] | None = None,
) -> torch.Tensor:
    """DDIM (Song et al. 2021, eta = 0) with v-prediction, zero-terminal-SNR, trailing spacing.

    `resample` r > 1 (with `known` positions): RePaint's resampling (Lugmayr et al. 2022), each
    step but the first and the last is taken r times; between takes the sample goes back from the
    next step's noise level to this step's by the forward process with fresh noise
    `jump_noise(i, j)` ((N, C, h, w), standard normal) and the known positions are set to this
    step's level, so the generated positions are denoised again against them. Without it the known
    positions are only pasted in after each step, which RePaint found leaves the generated part
    out of harmony with the known part at its boundary (here: frames next to a reference).

    `denoised_fn(x0, i) -> x0'` corrects the model's clean-sample estimate at step i before the
    update; the step keeps its noise estimate, so x_prev moves by sqrt(alpha_prev) (x0' - x0).

    The last step returns the x0 estimate (DDIM's update with alpha_prev = 1): diffusers derives
    the previous timestep as ``t - 1000 // steps``, which for step counts that do not divide
    1,000 (e.g. 7: last t = 142) lands on t = 0 instead of the clean sample.
    """
    if steps < 1:
        raise ValueError(f"DDIM needs at least 1 step, got {steps}")
    sched = scheduler if scheduler is not None else ddim_scheduler()
    sched.set_timesteps(steps, device=x_T.device)
    if resample < 1:
        raise ValueError(f"resample must be at least 1, got {resample}")
    x = x_T * sched.init_noise_sigma  # (N, C, h, w)
    for i, t in enumerate(sched.timesteps):
        takes = resample if known is not None and known.positions and 0 < i < steps - 1 else 1
        for j in range(takes):
            if j > 0:  # back from step i+1's level to step i's, then step i again
                if jump_noise is None:
                    raise ValueError("resample > 1 needs jump_noise")
                a_t = sched.alphas_cumprod[int(t)].to(x.device, torch.float32)
                a_next = sched.alphas_cumprod[int(sched.timesteps[i + 1])].to(x.device, torch.float32)
                ratio = a_t / a_next
                x = (ratio.sqrt() * x.float() + (1 - ratio).sqrt() * jump_noise(i, j).to(x.device, torch.float32)).to(x.dtype)
                x = known.at_level(x, a_t)  # type: ignore[union-attr]
            _check_cancel(cancel, i)
            v = model_fn(x, t)  # (N, C, h, w)
            out = sched.step(v, t, x)
            x = out.prev_sample if i < steps - 1 else out.pred_original_sample
            if denoised_fn is not None:
                x0 = out.pred_original_sample
                fixed = denoised_fn(x0, i)
                if i == steps - 1:
                    x = fixed
                else:  # DDIM's x_prev = sqrt(a_prev) x0 + sqrt(1 - a_prev) eps, eps unchanged (diffusers' a_prev)
                    prev_t = int(t) - sched.config.num_train_timesteps // sched.num_inference_steps
                    a_prev = sched.alphas_cumprod[prev_t] if prev_t >= 0 else sched.final_alpha_cumprod
                    x = x + a_prev.to(x.device, torch.float32).sqrt().to(x.dtype) * (fixed - x0)
            if known is not None:
                x = known.after_step(x, sched, i)
        if callback is not None:
            callback({"x": x, "i": i, "t": int(t), "denoised": out.pred_original_sample, "steps": steps})
    return x


@torch.no_grad()
def sample_lcm(
    model_fn: ModelFn,
    x_T: torch.Tensor,
    steps: int,
    *,
    callback: StepCallback | None = None,
    cancel: CancelToken | None = None,
    generator: torch.Generator | None = None,
    scheduler: LCMScheduler | None = None,
    known: Known | None = None,
    renoise: Callable[[int], torch.Tensor] | None = None,
    denoised_fn: Callable[[torch.Tensor, int], torch.Tensor] | None = None,
) -> torch.Tensor:
    """Latent Consistency Model multistep sampling (Luo et al. 2023, Alg. 1) with v-prediction.

    Between steps LCM re-noises its x0 estimate; `generator` makes that noise reproducible, or
    `renoise(i)` supplies it ((N, C, h, w), standard normal) after step i: the Renderer's per-frame
    noise (`RenderSettings.noise`), so that a frame's re-noising does not depend on its window.
    `denoised_fn(x0, i) -> x0'` corrects the consistency estimate at step i before it is re-noised
    (or returned, after the last step).
    """
    if steps < 1:
        raise ValueError(f"LCM needs at least 1 step, got {steps}")
    sched = scheduler if scheduler is not None else lcm_scheduler()
    sched.set_timesteps(steps, device=x_T.device)
    x = x_T * sched.init_noise_sigma  # (N, C, h, w)
    for i, t in enumerate(sched.timesteps):
        _check_cancel(cancel, i)
        v = model_fn(x, t)  # (N, C, h, w)
        out = sched.step(v, t, x, generator=generator)
        x = out.prev_sample
        denoised = out.denoised
        last = i == len(sched.timesteps) - 1
        if denoised_fn is not None:
            denoised = denoised_fn(out.denoised, i)
            if last:
                x = denoised
            elif renoise is None:  # the scheduler's re-noising, moved with its estimate
                a = sched.alphas_cumprod[int(sched.timesteps[i + 1])].to(x.device, torch.float32)
                x = x + (a.sqrt() * (denoised.float() - out.denoised.float())).to(x.dtype)
        if renoise is not None and not last:  # LCMScheduler.step's update with our noise
            a = sched.alphas_cumprod[int(sched.timesteps[i + 1])].to(x.device, torch.float32)
            x = (a.sqrt() * denoised.float() + (1 - a).sqrt() * renoise(i).to(x.device, torch.float32)).to(x.dtype)
        if known is not None:
            x = known.after_step(x, sched, i)
        if callback is not None:
            callback({"x": x, "i": i, "t": int(t), "denoised": denoised, "steps": steps})
    return x


# -- a window's noise and its lighting anchor: seeded per window or per shot frame (`RenderSettings.noise`), and
# `mean_anchor`, the `denoised_fn` that keeps an inferred region's latent mean between its references' (`RenderSettings.ref_dc`)

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
