"""LCM stage: latent consistency distillation of the video model for 2-step sampling (Luo et al. 2023, Alg. 1; paper Sec. Acceleration).

On the teacher's 50-step DDIM grid (skipping interval k = 20, LCMScheduler's
`original_inference_steps`), for t_n = 20 n - 1 and t_{n-1} = t_n - 20:

    x_{t_n}      = sqrt(a_n) x_0 + sqrt(1 - a_n) eps
    x_{t_{n-1}}  = DDIM step of the frozen teacher from t_n                     (no CFG, as sampling)
    f_theta(x,t) = c_skip(t) x + c_out(t) x0_theta(x, t)                        (boundary condition)
    L            = pseudo-Huber( f_theta(x_{t_n}, t_n), f_theta-(x_{t_{n-1}}, t_{n-1}) )

theta- is an EMA of theta (the target network). c_skip/c_out are diffusers' LCMScheduler
scalings, and x0_theta comes from the student's v-prediction, so `LCMScheduler.step` on the
distilled UNet's output is exactly f_theta. The student starts as a copy of the teacher;
the result is the teacher folder plus `lcm_unet.safetensors` (`predict_v(..., lcm=True)`).
"""
from __future__ import annotations

import copy
import dataclasses
import json
import logging
from pathlib import Path
from typing import Callable

import torch
from diffusers import UNet2DConditionModel

from x2video.model.checkpoint import load_into, read_config, save_checkpoint
from x2video.model.unet import build_unet
from x2video.sampling.samplers import lcm_scheduler
from x2video.train.batches import Batch, LatentData, video_batches
from x2video.train.config import LCMStageConfig
from x2video.train.diffusion import check_noise_shared, diffusion_batch, noise_scheduler, predict, window_noise
from x2video.train.loop import LoopConfig, StepLog, train
from x2video.train.runs import check_same_vae, load_vae, model_dir, write_results

log = logging.getLogger(__name__)


def x0_eps_from_v(x_t: torch.Tensor, v: torch.Tensor, a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """v-parameterisation -> (x0, eps); a (BN, 1, 1, 1) alpha_cumprod."""
    return a.sqrt() * x_t - (1 - a).sqrt() * v, (1 - a).sqrt() * x_t + a.sqrt() * v


class LCMLoss:
    """The consistency distillation loss above, with the target network as state."""

    def __init__(self, student: UNet2DConditionModel, teacher: UNet2DConditionModel, target: UNet2DConditionModel, stage: LCMStageConfig,
                 prediction: str = "v") -> None:
        self.student, self.teacher, self.target, self.stage = student, teacher, target, stage
        self.prediction = prediction  # what the UNets output (`ModelConfig.prediction`); predict() converts to v
        self.alphas = noise_scheduler().alphas_cumprod.float()  # (1000,)
        self.lcm = lcm_scheduler()
        if stage.ddim_steps != self.lcm.config.original_inference_steps:
            raise ValueError(f"ddim_steps {stage.ddim_steps} != LCMScheduler.original_inference_steps {self.lcm.config.original_inference_steps}")
        self.interval = self.alphas.shape[0] // stage.ddim_steps

    @torch.no_grad()
    def update_target(self) -> None:
        """theta- <- EMA(theta) (called before each step, i.e. after the previous optimiser step)."""
        tp = [p for p in self.target.parameters()]
        sp = [p.detach() for p in self.student.parameters()]
        torch._foreach_lerp_(tp, sp, 1 - self.stage.target_ema)

    def scalings(self, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        c_skip, c_out = self.lcm.get_scalings_for_boundary_condition_discrete(t.float())
        return c_skip[:, None, None, None], c_out[:, None, None, None]

    def __call__(self, b: Batch, step: int) -> tuple[torch.Tensor, dict[str, float]]:
        self.update_target()
        dev = b.x0.device
        alphas = self.alphas.to(dev)
        n_idx = torch.randint(0, self.stage.ddim_steps, (b.windows,), device=dev)  # (B,)
        t = (n_idx + 1) * self.interval - 1  # (B,) in 19..999
        t_prev = t - self.interval  # (B,) in -1..979
        tf = t.repeat_interleave(b.num_frames)  # (BN,)
        tpf = t_prev.clamp(min=0).repeat_interleave(b.num_frames)
        a = alphas[tf][:, None, None, None]
        a_prev = torch.where(t_prev.repeat_interleave(b.num_frames) >= 0, alphas[tpf], torch.ones_like(alphas[tpf]))[:, None, None, None]
        noise = window_noise(b.x0, b.num_frames, self.stage.noise_shared)  # (BN, 4, h, w), frames of a window share a part
        x_t = a.sqrt() * b.x0 + (1 - a).sqrt() * noise  # (BN, 4, h, w)

        c_skip, c_out = self.scalings(tf)
        x0_s, _ = x0_eps_from_v(x_t, predict(self.student, x_t, t, b, self.prediction), a)
        pred = c_skip * x_t + c_out * x0_s
        with torch.no_grad():
            x0_T, eps_T = x0_eps_from_v(x_t, predict(self.teacher, x_t, t, b, self.prediction), a)
            x_prev = a_prev.sqrt() * x0_T + (1 - a_prev).sqrt() * eps_T  # DDIM (eta 0) step to t_prev
            x0_tg, _ = x0_eps_from_v(x_prev, predict(self.target, x_prev, t_prev.clamp(min=0), b, self.prediction), a_prev)
            cs, co = self.scalings(tpf)
            target = cs * x_prev + co * x0_tg
        c = self.stage.huber_c
        loss = (((pred.float() - target.float()) ** 2 + c * c).sqrt() - c).mean()
        return loss, {"t_mean": float(t.float().mean())}


def run_lcm_stage(teacher: str | Path, cache: str | Path, out_dir: str | Path, stage: LCMStageConfig, loop: LoopConfig,
                  on_step: Callable[[StepLog], None] | None = None, student_init: str | Path | None = None) -> dict:
    """Distil the video model of `teacher` (a run or model folder) into an LCM UNet.

    The student (and the target network, its EMA) starts from the teacher, or from `student_init`'s
    `lcm_unet.safetensors` (an LCM run or shipped folder of the same architecture), so a teacher
    continued from a distilled model's teacher can be re-distilled from that student instead of from
    scratch."""
    cache, out_dir = Path(cache), Path(out_dir)
    check_noise_shared(stage.noise_shared)
    d = model_dir(teacher)
    cfg = read_config(d)
    if not cfg.video:
        raise ValueError(f"{d} holds an image model; --teacher wants the video stage's run or model")
    check_same_vae(cfg, read_config(cache / "model"), f"teacher {teacher}")
    from x2video.train.cache import read_info

    cache_prior = read_info(cache).prior
    if cfg.shading_prior and cache_prior != cfg.prior:
        raise ValueError(f"teacher {teacher} samples over the {cfg.prior!r} prior, the cache {cache} holds the "
                         f"{cache_prior!r} prior; distil on a cache of the teacher's prior")
    teacher_unet = build_unet(cfg)
    load_into(teacher_unet, d / "unet.safetensors", "unet")
    teacher_unet.eval().requires_grad_(False)
    student = copy.deepcopy(teacher_unet).train().requires_grad_(True)
    init_dir = None
    if student_init is not None:
        init_dir = model_dir(student_init).resolve()
        init_cfg = read_config(init_dir)
        if not (init_dir / "lcm_unet.safetensors").is_file():
            raise FileNotFoundError(f"--student-init {student_init}: {init_dir} has no lcm_unet.safetensors (an LCM run or shipped model)")
        # shapes are load_into's to check (it names every mismatched tensor); what loads but means
        # something else is the target the UNet predicts
        if (init_cfg.prediction, init_cfg.residual_prior) != (cfg.prediction, cfg.residual_prior):
            raise ValueError(f"--student-init {student_init}: predicts {init_cfg.prediction} (residual_prior={init_cfg.residual_prior}), "
                             f"the teacher {cfg.prediction} (residual_prior={cfg.residual_prior})")
        load_into(student, init_dir / "lcm_unet.safetensors", "lcm_unet")
        log.info("LCM student initialised from %s", init_dir)
    target = copy.deepcopy(student).eval().requires_grad_(False)
    _, vae = load_vae(d)
    data = LatentData(cache, "train", cfg.latent_scales, cfg.shading_prior)
    loss = LCMLoss(student, teacher_unet, target, stage, cfg.prediction)

    def loss_fn(b: Batch, step: int):
        dev = next(student.parameters()).device
        teacher_unet.to(dev)
        target.to(dev)
        return loss(diffusion_batch(b.to(dev), cfg.residual_prior), step)

    def save(module: torch.nn.Module, out: Path) -> None:
        save_checkpoint(out, cfg, {"unet": teacher_unet, "vae": vae, "lcm_unet": module})

    sc = {"stage": "lcm", **dataclasses.asdict(stage), "model": cfg.to_dict(), "cache": str(cache.resolve()), "teacher": str(d.resolve())}
    if init_dir is not None:
        sc["student_init"] = str(init_dir)
    ck = train(module=student, loss_fn=loss_fn, batches=video_batches(data, stage.batch, stage.augment, stage.window, stage.seed, loop.workers),
               save_fn=save, out_dir=out_dir, cfg=loop, stage_config=sc, batch_size=stage.batch * stage.window.frames,
               on_step=on_step, extra_state={"target": target})
    summary = json.loads((out_dir / "summary.json").read_text()) if (out_dir / "summary.json").is_file() else {}
    result = {"checkpoint": str(ck), "model": str(ck / "model"), "step": int(ck.name.split("-")[-1]), "speed": summary}
    write_results(out_dir, "lcm", result)
    return result
