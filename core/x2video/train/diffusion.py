"""The v-prediction diffusion loss (paper eq. loss) on the SD 2.1 schedule with zero-terminal-SNR rescaling.

    x_t = sqrt(a_t) x_0 + sqrt(1 - a_t) eps,   v = sqrt(a_t) eps - sqrt(1 - a_t) x_0
    L   = || v - v_theta(x_t, t, c) ||^2

One timestep per window (a window is denoised jointly at inference), fresh noise per frame.
The schedule is the sampler's (`x2video.sampling.samplers.SCHEDULE`), so what is trained is
what DDIM/LCM sample.
"""
from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F
from diffusers import DDPMScheduler, UNet2DConditionModel

from x2video.model.inputs import prior_latents, run_unet
from x2video.sampling.samplers import SCHEDULE, mix_noise
from x2video.train.batches import Batch


def noise_scheduler() -> DDPMScheduler:
    """The training noise schedule: SD 2.1 scaled-linear betas, zero terminal SNR, v-prediction."""
    keys = ("num_train_timesteps", "beta_start", "beta_end", "beta_schedule", "prediction_type", "rescale_betas_zero_snr", "clip_sample")
    return DDPMScheduler(**{k: SCHEDULE[k] for k in keys})


def diffusion_batch(b: Batch, residual: bool) -> Batch:
    """The batch the diffusion sees: targets x0 are the RGB latents, or for a residual-prior model
    (`ModelConfig.residual_prior`) the RGB latents minus the shading prior's latents in `b.cond`
    (zero where the prior is dropped or masked out, so there the target is the RGB latent).
    References stay RGB latents: at sampling they are earlier frames' finished latents."""
    return dataclasses.replace(b, x0=b.x0 - prior_latents(b.cond)) if residual else b


def predict(unet: UNet2DConditionModel, x_t: torch.Tensor, t: torch.Tensor, b: Batch, prediction: str = "v") -> torch.Tensor:
    """v_theta for a batch: x_t (BN, 4, h, w), t (B,) per window -> (BN, 4, h, w); an x0-predicting
    UNet (`prediction="sample"`) is converted to v."""
    return run_unet(
        unet, x_t, t, b.cond, b.ref,
        num_frames=b.num_frames, text_global=b.text_global, ref_positions=b.ref_positions,
        mode=b.mode, level=b.level, text_local=b.text_local, local_masks=b.local_masks, prediction=prediction,
    )


def check_noise_shared(value: float) -> None:
    """`--noise-shared` of the video and LCM stages: a fraction in [0, 1], refused before a run starts."""
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"--noise-shared must lie in [0, 1], got {value}")


def window_noise(x0: torch.Tensor, num_frames: int, shared: float = 0.0, generator: torch.Generator | None = None) -> torch.Tensor:
    """(B*N, C, h, w) standard normal noise for a batch of windows of `num_frames` frames, a fraction
    `shared` of whose variance the frames of each window share: the mixed noise prior the Renderer
    samples with (`RenderSettings.noise_shared`, `x2video.sampling.samplers.frame_noise`), so a model
    trained with it sees at training what it is given at inference. 0: independent noise per frame."""
    if x0.shape[0] % num_frames:
        raise ValueError(f"{x0.shape[0]} frames are not whole windows of {num_frames}")
    dev = x0.device if generator is None else "cpu"  # a seeded (CPU) generator draws on the CPU
    own = torch.randn(x0.shape, generator=generator, device=dev).to(x0.device, x0.dtype)
    if shared == 0.0:
        return own
    common = torch.randn((x0.shape[0] // num_frames, *x0.shape[1:]), generator=generator, device=dev).to(x0.device, x0.dtype)
    return mix_noise(own, common.repeat_interleave(num_frames, 0), shared)


#: min-SNR-gamma (Hang et al. 2023) of the x0-predicting models' loss
MIN_SNR_GAMMA = 5.0


def v_loss(unet: UNet2DConditionModel, sched: DDPMScheduler, b: Batch, prediction: str = "v",
           noise_shared: float = 0.0) -> tuple[torch.Tensor, dict[str, float]]:
    """MSE between predicted and true velocity for random per-window timesteps.

    For an x0-predicting UNet the v error is (x0 error) / sqrt(1 - a), i.e. the x0 error weighted
    by 1 + SNR, which reaches 1,176 at t = 0 and would spend the gradient on nearly clean inputs;
    there the per-frame weight is min(1 + SNR, gamma) / (1 + SNR) = min(1, gamma (1 - a)) with
    gamma = MIN_SNR_GAMMA (min-SNR weighting of the x0 loss, Hang et al. 2023). `noise_shared`: the
    fraction of the noise's variance a window's frames share (`window_noise`)."""
    bn = b.x0.shape[0]
    t = torch.randint(0, sched.config.num_train_timesteps, (b.windows,), device=b.x0.device)  # (B,)
    t_frames = t.repeat_interleave(b.num_frames)  # (BN,)
    noise = window_noise(b.x0, b.num_frames, noise_shared)
    x_t = sched.add_noise(b.x0, noise, t_frames)
    target = sched.get_velocity(b.x0, noise, t_frames)
    v = predict(unet, x_t, t, b, prediction)
    if prediction == "sample":
        a = sched.alphas_cumprod.to(b.x0.device)[t_frames].float()  # (BN,)
        w = torch.clamp(MIN_SNR_GAMMA * (1 - a), max=1.0).view(-1, 1, 1, 1)
        loss = (w * (v.float() - target.float()) ** 2).mean()
    else:
        loss = F.mse_loss(v.float(), target.float())
    return loss, {"t_mean": float(t.float().mean()), "frames": float(bn)}


#: timesteps the held-out loss averages over (fixed, so runs compare)
HELDOUT_T = (50, 250, 500, 750, 950)


@torch.no_grad()
def heldout_v_loss(unet: UNet2DConditionModel, batches: list[Batch], seed: int = 0, prediction: str = "v", noise_shared: float = 0.0) -> float:
    """Mean v-prediction MSE over fixed held-out batches at fixed timesteps `HELDOUT_T`, seeded noise:
    a cheap, comparable number (e.g. shading prior on vs off) before rendering anything."""
    sched = noise_scheduler()
    was_training = unet.training
    unet.eval()
    dev = next(unet.parameters()).device
    g = torch.Generator().manual_seed(seed)
    total, n = 0.0, 0
    for b in batches:
        b = b.to(dev)
        for t in HELDOUT_T:
            tw = torch.full((b.windows,), t, device=dev, dtype=torch.long)
            noise = window_noise(b.x0, b.num_frames, noise_shared, g)
            tf = tw.repeat_interleave(b.num_frames)
            v = predict(unet, sched.add_noise(b.x0, noise, tf), tw, b, prediction)
            total += float(F.mse_loss(v.float(), sched.get_velocity(b.x0, noise, tf).float()))
            n += 1
    unet.train(was_training)
    return total / max(n, 1)
