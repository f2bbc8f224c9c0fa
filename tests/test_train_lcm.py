"""LCM distillation trains exactly the consistency function diffusers' LCMScheduler samples with."""
from __future__ import annotations

import torch

from x2video.sampling.samplers import lcm_scheduler
from x2video.train.diffusion import noise_scheduler
from x2video.train.lcm_stage import LCMLoss, LCMStageConfig, x0_eps_from_v


def _loss_without_unets() -> LCMLoss:
    unet = torch.nn.Linear(1, 1)  # LCMLoss only keeps references; the math below needs no UNet
    return LCMLoss(unet, unet, unet, LCMStageConfig())


def test_student_parameterisation_matches_lcm_scheduler_step():
    loss = _loss_without_unets()
    sched = lcm_scheduler()
    sched.set_timesteps(2)
    g = torch.Generator().manual_seed(0)
    x_t = torch.randn(2, 4, 3, 5, generator=g)
    v = torch.randn(2, 4, 3, 5, generator=g)
    for t in sched.timesteps:  # 999, then 499
        out = sched.step(v, t, x_t, generator=torch.Generator().manual_seed(1))
        a = noise_scheduler().alphas_cumprod[int(t)].float().expand(2)[:, None, None, None]
        x0, _ = x0_eps_from_v(x_t, v, a)
        c_skip, c_out = loss.scalings(torch.full((2,), int(t)))
        torch.testing.assert_close(c_skip * x_t + c_out * x0, out.denoised, rtol=1e-5, atol=1e-5)


def test_grid_and_boundary_condition():
    loss = _loss_without_unets()
    assert loss.interval == 20  # LCMScheduler's 50-step original grid: t = 19, 39, ..., 999
    c_skip, c_out = loss.scalings(torch.zeros(1))
    assert float(c_skip) == 1.0 and float(c_out) == 0.0  # f(x, 0) = x: the target at t_prev < 0 is the teacher's x0
    # v -> (x0, eps) inverts the forward process
    a = torch.tensor(0.3).view(1, 1, 1, 1)
    x0, eps = torch.randn(1, 4, 2, 2), torch.randn(1, 4, 2, 2)
    x_t = a.sqrt() * x0 + (1 - a).sqrt() * eps
    v = a.sqrt() * eps - (1 - a).sqrt() * x0
    r0, re = x0_eps_from_v(x_t, v, a)
    torch.testing.assert_close(r0, x0) and torch.testing.assert_close(re, eps)
