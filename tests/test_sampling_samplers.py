"""DDIM / LCM samplers: oracle recovery, schedule conventions, callbacks, cancel within one step."""
from __future__ import annotations

import pytest
import torch

from x2video.render.events import Cancelled, CancelToken
from x2video.sampling.samplers import Known, alphas_cumprod, ddim_scheduler, lcm_scheduler, sample_ddim, sample_lcm


def _oracle(x0: torch.Tensor, seen: list | None = None):
    ac = alphas_cumprod().float()

    def fn(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        a = ac[int(t)]
        if seen is not None:
            seen.append((int(t), x.clone()))
        eps = (x - a.sqrt() * x0) / (1 - a).sqrt()
        return a.sqrt() * eps - (1 - a).sqrt() * x0  # the true v

    return fn


def _data(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(3, 4, 6, 8, generator=g), torch.randn(3, 4, 6, 8, generator=g)


def test_schedule_is_zero_terminal_snr_trailing() -> None:
    ac = alphas_cumprod()
    assert ac[-1] == 0 and abs(float(ac[0]) - (1 - 0.00085)) < 1e-6
    s = ddim_scheduler()
    s.set_timesteps(4)
    assert s.timesteps.tolist() == [999, 749, 499, 249]
    s = lcm_scheduler()
    s.set_timesteps(2)
    assert s.timesteps.tolist() == [999, 499]


@pytest.mark.parametrize("steps", [1, 2, 4, 7, 20])
def test_ddim_oracle_recovers_clean_latent(steps: int) -> None:
    x0, eps = _data()
    seen: list = []
    out = sample_ddim(_oracle(x0, seen), eps, steps)
    assert torch.allclose(out, x0, atol=1e-5)
    assert len(seen) == steps and seen[0][0] == 999
    # t=999 has alpha_cumprod = 0: the first input is pure noise and v-prediction still gives x0
    assert torch.equal(seen[0][1], eps)
    if 1000 % steps == 0:  # DDIM (eta=0) keeps the same noise: every x_t is on the forward process
        ac = alphas_cumprod().float()
        for t, x in seen:
            assert torch.allclose(x, ac[t].sqrt() * x0 + (1 - ac[t]).sqrt() * eps, atol=1e-5), t


def test_ddim_wrong_model_does_not_recover() -> None:
    x0, eps = _data()
    out = sample_ddim(_oracle(x0 + 0.5), eps, 4)
    assert (out - x0).abs().mean() > 0.4


@pytest.mark.parametrize("steps", [1, 2, 4])
def test_lcm_oracle_recovers_clean_latent_and_is_seeded(steps: int) -> None:
    x0, eps = _data()
    out = sample_lcm(_oracle(x0), eps, steps, generator=torch.Generator().manual_seed(3))
    assert torch.allclose(out, x0, atol=1e-5)
    # an imperfect model: LCM's re-noising between steps makes the result depend on the generator
    model = _oracle(x0 + 0.3)
    noisy = lambda x, t: model(x, t) + 0.2 * torch.tanh(x)  # noqa: E731
    a = sample_lcm(noisy, eps, 2, generator=torch.Generator().manual_seed(1))
    b = sample_lcm(noisy, eps, 2, generator=torch.Generator().manual_seed(1))
    c = sample_lcm(noisy, eps, 2, generator=torch.Generator().manual_seed(2))
    assert torch.equal(a, b) and not torch.equal(a, c)


@pytest.mark.parametrize("sampler", [sample_ddim, sample_lcm])
def test_callback_reports_every_step(sampler) -> None:
    x0, eps = _data()
    infos: list[dict] = []
    sampler(_oracle(x0), eps, 4, callback=infos.append)
    assert [i["i"] for i in infos] == [0, 1, 2, 3] and all(i["steps"] == 4 for i in infos)
    assert {"x", "i", "t", "denoised"} <= set(infos[0])
    assert torch.allclose(infos[-1]["denoised"], x0, atol=1e-5)


@pytest.mark.parametrize("sampler", [sample_ddim, sample_lcm])
@pytest.mark.parametrize("cancel_at", [0, 2])
def test_cancel_stops_within_one_step(sampler, cancel_at: int) -> None:
    x0, eps = _data()
    token = CancelToken()
    calls: list = []
    oracle = _oracle(x0, calls)

    def fn(x, t):
        if len(calls) == cancel_at:
            token.cancel()  # set while step `cancel_at` runs (as a GUI thread would)
        return oracle(x, t)

    with pytest.raises(Cancelled):
        sampler(fn, eps, 20 if sampler is sample_ddim else 4, cancel=token)
    assert len(calls) == cancel_at + 1  # the running step finishes, no further model call


def test_bad_step_count() -> None:
    with pytest.raises(ValueError, match="at least 1 step"):
        sample_ddim(lambda x, t: x, torch.zeros(1, 4, 2, 2), 0)


@pytest.mark.parametrize("sampler", [sample_ddim, sample_lcm])
def test_known_positions_follow_the_noised_reference(sampler) -> None:
    """Between steps the known positions hold sqrt(a) x0 + sqrt(1 - a) eps at the next step's level;
    the other positions are the sampler's own, and the last step is not overwritten."""
    x0, eps = _data()
    ref = torch.randn(2, 4, 6, 8, generator=torch.Generator().manual_seed(5))
    model = _oracle(x0 + 0.3)  # a wrong model: left alone, position 0 and 2 drift towards x0 + 0.3
    kwargs = {"generator": torch.Generator().manual_seed(1)} if sampler is sample_lcm else {}
    seen: list = []
    known = Known((0, 2), ref, eps[[0, 2]])
    out = sampler(lambda x, t: (seen.append((int(t), x.clone())), model(x, t))[1], eps, 4, known=known, **kwargs)
    ac = alphas_cumprod().float()
    for t, x in seen[1:]:
        assert torch.allclose(x[[0, 2]], ac[t].sqrt() * ref + (1 - ac[t]).sqrt() * eps[[0, 2]], atol=1e-5), t
    plain: list = []
    kwargs = {"generator": torch.Generator().manual_seed(1)} if sampler is sample_lcm else {}
    sampler(lambda x, t: (plain.append(x.clone()), model(x, t))[1], eps, 4, **kwargs)
    assert not torch.allclose(plain[1][[0, 2]], seen[1][1][[0, 2]], atol=1e-3)  # replacement changed them
    # the returned sample is the model's estimate everywhere (the caller keeps the generated positions)
    assert out.shape == eps.shape and not torch.allclose(out[[0, 2]], ref, atol=1e-2)


def test_lcm_renoise_supplies_the_noise_between_steps() -> None:
    """With `renoise`, each step after the first sees sqrt(a) x0_est + sqrt(1 - a) renoise(i): the
    Renderer's per-frame noise replaces the generator's draw, which then has no effect."""
    x0, x_T = _data(1)
    ac = alphas_cumprod().float()
    z = [torch.randn(3, 4, 6, 8, generator=torch.Generator().manual_seed(10 + i)) for i in range(3)]
    runs = []
    for gseed in (0, 1):
        seen: list = []
        denoised: list = []
        out = sample_lcm(_oracle(x0 + 0.3, seen), x_T, 4, generator=torch.Generator().manual_seed(gseed),
                         renoise=lambda i: z[i], callback=lambda info: denoised.append(info["denoised"]))
        for i in range(3):
            t_next = seen[i + 1][0]
            assert torch.allclose(seen[i + 1][1], ac[t_next].sqrt() * denoised[i] + (1 - ac[t_next]).sqrt() * z[i], atol=1e-5)
        runs.append(out)
    assert torch.equal(runs[0], runs[1])


def test_ddim_resample_goes_back_one_step_and_repeats_it() -> None:
    """RePaint resampling: with known positions, every step but the first and last is taken r times;
    between takes the sample is carried back from the next step's level to this step's by the forward
    process with `jump_noise(i, j)`, and the known positions are set to this step's level."""
    x0, eps = _data()
    ref = torch.randn(1, 4, 6, 8, generator=torch.Generator().manual_seed(5))
    target = torch.cat([ref, x0[1:]])  # the oracle's clean sample agrees with the known frame
    ac = alphas_cumprod().float()
    draws: dict = {}

    def jump_noise(i: int, j: int) -> torch.Tensor:
        draws[(i, j)] = torch.randn(3, 4, 6, 8, generator=torch.Generator().manual_seed(100 * i + j))
        return draws[(i, j)]

    seen: list = []
    known = Known((0,), ref, eps[[0]])
    out = sample_ddim(_oracle(target, seen), eps, 4, known=known, resample=3, jump_noise=jump_noise)
    assert [t for t, _ in seen] == [999, 749, 749, 749, 499, 499, 499, 249]
    assert sorted(draws) == [(1, 1), (1, 2), (2, 1), (2, 2)]
    # the second take of step 1 (t=749) starts from step 1's output (level 499) carried back to 749
    a_t, a_next = ac[749], ac[499]
    after = a_next.sqrt() * target + (1 - a_next).sqrt() * eps  # the oracle keeps DDIM on the forward process
    back = (a_t / a_next).sqrt() * after + (1 - a_t / a_next).sqrt() * draws[(1, 1)]
    assert torch.allclose(seen[2][1][1:], back[1:], atol=1e-5)
    assert torch.allclose(seen[2][1][0], a_t.sqrt() * ref[0] + (1 - a_t).sqrt() * eps[0], atol=1e-5)  # known at this level
    assert torch.allclose(out, target, atol=1e-4)  # an exact model still lands on its clean sample
    # without known positions there is nothing to harmonise with: one take per step
    plain: list = []
    sample_ddim(_oracle(x0, plain), eps, 4, resample=3, jump_noise=jump_noise)
    assert len(plain) == 4
    with pytest.raises(ValueError, match="resample must be at least 1"):
        sample_ddim(_oracle(x0), eps, 4, known=known, resample=0)
    with pytest.raises(ValueError, match="needs jump_noise"):
        sample_ddim(_oracle(x0), eps, 4, known=known, resample=2)


def test_ddim_denoised_fn_moves_the_clean_estimate_and_keeps_the_noise() -> None:
    """`denoised_fn` corrects x0 at each step: the next input is sqrt(a) x0' + sqrt(1 - a) eps with the
    step's own noise estimate, and the last step returns the corrected estimate."""
    x0, eps = _data()
    ac = alphas_cumprod().float()
    calls: list = []

    def shift(z: torch.Tensor, i: int) -> torch.Tensor:
        calls.append(i)
        return z + 0.25

    seen: list = []
    out = sample_ddim(_oracle(x0, seen), eps, 4, denoised_fn=shift)
    assert calls == [0, 1, 2, 3]
    t1 = seen[1][0]
    assert t1 == 749 and torch.allclose(seen[1][1], ac[t1].sqrt() * (x0 + 0.25) + (1 - ac[t1]).sqrt() * eps, atol=1e-5)
    # the oracle keeps answering with x0, so each step's estimate is x0 again and its correction x0 + 0.25
    assert torch.allclose(out, x0 + 0.25, atol=1e-5)
