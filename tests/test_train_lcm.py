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


def test_noise_shared_draws_the_mixed_prior_per_window(monkeypatch):
    """--noise-shared: the noisy latents the student, teacher and target see carry the renderer's mixed
    noise prior; frames of one window share a fraction of it, frames of different windows none."""
    import x2video.train.lcm_stage as lcm_stage
    from x2video.train.batches import Batch

    seen: list[tuple[torch.Tensor, torch.Tensor]] = []

    def fake_predict(unet, x_t, t, b, prediction):  # records the student's input; v = 0 keeps the rest finite
        seen.append((x_t.detach().clone(), t.clone()))
        return torch.zeros_like(x_t)

    monkeypatch.setattr(lcm_stage, "predict", fake_predict)
    monkeypatch.setattr(LCMLoss, "update_target", lambda self: None)
    n, windows = 4, 64
    b = Batch(torch.zeros(windows * n, 4, 8, 8), torch.zeros(windows * n, 1, 8, 8), None, (), "key", 1, n,
              torch.zeros(windows, 1, 2), None, None)
    for shared in (0.0, 0.95):
        seen.clear()
        torch.manual_seed(0)
        unet = torch.nn.Linear(1, 1)
        LCMLoss(unet, unet, unet, LCMStageConfig(noise_shared=shared))(b, 0)
        x_t, t = seen[0]  # the student's call: x_t = sqrt(1 - a) * noise with x0 = 0
        a = noise_scheduler().alphas_cumprod[t].float().repeat_interleave(n)[:, None, None, None]
        noise = (x_t / (1 - a).sqrt()).reshape(windows, n, -1)
        same = torch.stack([torch.corrcoef(w)[0, 1:] for w in noise]).mean()
        other = torch.corrcoef(noise[:, 0])[0, 1:].mean()  # signed: 0 in expectation, ~0.01 of chance here
        assert abs(float(same) - shared) < 0.05 and abs(float(other)) < 0.05
        assert abs(float(noise.std()) - 1.0) < 0.05


def test_noise_shared_out_of_range_is_refused(tmp_path):
    import pytest

    from x2video.train.lcm_stage import run_lcm_stage
    from x2video.train.loop import LoopConfig

    with pytest.raises(ValueError, match="noise-shared must lie in"):
        run_lcm_stage(tmp_path / "no-teacher", tmp_path / "no-cache", tmp_path / "out", LCMStageConfig(noise_shared=1.5), LoopConfig(steps=1))
