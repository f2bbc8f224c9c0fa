"""The one training loop every stage shares: accelerate, EMA, resumable step checkpoints, a JSON loss log.

A stage supplies the trainable module, a `loss_fn(batch, step) -> (loss, logs)`, an infinite
batch iterator and a `save_fn(module, dir)` that writes the module in its own
`save_pretrained` format. The loop owns everything else, so `vae`, `image`, `video` and
`lcm` stages checkpoint, resume and log the same way on a CPU, one GPU or many
(`accelerate launch`).
"""
from __future__ import annotations

import json
import logging
import math
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import torch
from safetensors.torch import load_file, save_file

from x2video.io.atomic import write_json_atomic
from x2video.train.config import LoopConfig

log = logging.getLogger(__name__)

CKPT_PREFIX = "step-"


@dataclass
class StepLog:
    step: int
    loss: float
    steps_per_s: float
    samples_per_s: float
    lr: float
    extra: dict[str, float] = field(default_factory=dict)
    timing: dict[str, float] | None = None
    """Set once (on the step the timing measurement ends): mean seconds per step spent in
    `data` (next batch), `forward` (loss_fn), `backward` (backward + clip + optimiser + EMA)."""


#: steps measured for the data/forward/backward split (after the first, which warms caches up)
TIMING_STEPS = 10


def process_index() -> int:
    """This process's rank under `accelerate launch` (0 alone): batch sources mix it into their
    seed so that every process draws different samples."""
    from accelerate import PartialState

    return int(PartialState().process_index)


def list_checkpoints(out_dir: Path) -> list[Path]:
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        return []
    cks = [p for p in out_dir.iterdir() if p.is_dir() and p.name.startswith(CKPT_PREFIX) and (p / "state.json").exists()]
    return sorted(cks, key=lambda p: int(p.name[len(CKPT_PREFIX):]))


def latest_checkpoint(out_dir: Path) -> Path | None:
    cks = list_checkpoints(out_dir)
    return cks[-1] if cks else None


def _lr_lambda(cfg: LoopConfig) -> Callable[[int], float]:
    def f(step: int) -> float:
        warm = min(1.0, (step + 1) / max(1, cfg.warmup))
        decay = 0.5 ** (step // cfg.lr_half_every) if cfg.lr_half_every > 0 else 1.0
        return warm * decay

    return f


def _param_groups(module: torch.nn.Module, params: list[torch.nn.Parameter], lr: float,
                  lr_mult: Callable[[str], float] | None) -> list[dict[str, Any]]:
    """AdamW groups by learning-rate multiplier, in first-seen order (checkpoints index `params` in its own order)."""
    if lr_mult is None:
        return [{"params": params, "lr": lr}]
    names = {id(p): n for n, p in module.named_parameters()}
    groups: dict[float, list[torch.nn.Parameter]] = {}
    for p in params:
        if id(p) not in names:
            raise ValueError("lr_mult needs every trained parameter to belong to the module")
        groups.setdefault(float(lr_mult(names[id(p)])), []).append(p)
    return [{"params": ps, "lr": lr * m} for m, ps in groups.items()]


def train(
    *,
    module: torch.nn.Module,
    loss_fn: Callable[[Any, int], tuple[torch.Tensor, dict[str, float]]],
    batches: Iterator[Any] | Callable[[int], Iterator[Any]],
    save_fn: Callable[[torch.nn.Module, Path], None],
    out_dir: Path,
    cfg: LoopConfig,
    stage_config: dict[str, Any],
    batch_size: int,
    params: list[torch.nn.Parameter] | None = None,
    on_step: Callable[[StepLog], None] | None = None,
    extra_state: dict[str, torch.nn.Module] | None = None,
    lr_mult: Callable[[str], float] | None = None,
) -> Path:
    """Train `module` until `cfg.steps`, resuming from the newest checkpoint in `out_dir`.

    `batches` is an iterator, or a function of the first step to run (0, or the resumed
    step) returning one, so a resumed run draws fresh batches instead of replaying the
    first ones. `extra_state` modules (e.g. LCM's target network) are saved in every
    checkpoint and restored on resume. Writes `log.json` (loss curve), `summary.json`
    (speed and the step-time split) and `step-XXXXXXXXX/` checkpoints into `out_dir`.

    `lr_mult(name)` scales the learning rate of `module`'s parameter `name` (its own AdamW group;
    the schedule applies to every group alike); None: one rate for all.

    Returns the directory of the final checkpoint, whose `model/` holds the EMA weights
    (or the raw weights when EMA is off) in the stage's own format.
    """
    from accelerate import Accelerator
    from accelerate.utils import set_seed

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    accel = Accelerator(mixed_precision=cfg.mixed_precision, cpu=not torch.cuda.is_available())
    set_seed(cfg.seed)
    params = [p for p in (params if params is not None else module.parameters()) if p.requires_grad]
    opt = torch.optim.AdamW(_param_groups(module, params, cfg.lr, lr_mult), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, _lr_lambda(cfg))
    module, opt = accel.prepare(module, opt)
    ema = [p.detach().clone().float() for p in params] if cfg.ema_decay > 0 else None

    extra_state = dict(extra_state or {})
    stage_config = json.loads(json.dumps(stage_config))  # tuples -> lists, as state.json holds them
    step = 0
    history: list[dict[str, Any]] = []
    resume = latest_checkpoint(out_dir)
    if resume is not None:
        state = json.loads((resume / "state.json").read_text())
        if state.get("stage_config") != stage_config:
            raise ValueError(
                f"checkpoint {resume} was trained with another stage config; use a new --out or the same config "
                f"(saved: {state.get('stage_config')}, now: {stage_config})"
            )
        raw = load_file(str(resume / "train_params.safetensors"))
        with torch.no_grad():
            for i, p in enumerate(params):
                p.copy_(raw[f"p{i}"])
            if ema is not None:
                for i, e in enumerate(ema):
                    e.copy_(raw.get(f"ema{i}", raw[f"p{i}"]))
        if extra_state:
            extra = load_file(str(resume / "extra_state.safetensors"))
            for name, mod in extra_state.items():
                mod.load_state_dict({k.removeprefix(f"{name}."): v for k, v in extra.items() if k.startswith(f"{name}.")})
        opt.load_state_dict(torch.load(resume / "optimizer.pt", weights_only=True, map_location="cpu"))
        step = int(state["step"])
        sched.last_epoch = step  # the schedule as if `step` optimiser steps had run
        for group, base in zip(opt.param_groups, sched.base_lrs):
            group["lr"] = base * _lr_lambda(cfg)(step)
        history = json.loads((out_dir / "log.json").read_text()) if (out_dir / "log.json").exists() else []
        history = [h for h in history if h["step"] <= step]
        log.info("resumed from %s at step %d", resume, step)

    def checkpoint() -> Path:
        ck = out_dir / f"{CKPT_PREFIX}{step:09d}"
        accel.wait_for_everyone()
        if accel.is_main_process:  # several processes (accelerate launch): one writes
            _write_checkpoint(ck)
        accel.wait_for_everyone()
        return ck

    def _write_checkpoint(ck: Path) -> None:
        tmp = out_dir / f".tmp-{ck.name}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        tensors = {f"p{i}": p.detach().cpu().contiguous() for i, p in enumerate(params)}
        if ema is not None:
            tensors.update({f"ema{i}": e.cpu().contiguous() for i, e in enumerate(ema)})
        save_file(tensors, str(tmp / "train_params.safetensors"))
        if extra_state:
            extra = {f"{n}.{k}": v.detach().cpu().contiguous() for n, m in extra_state.items() for k, v in m.state_dict().items()}
            save_file(extra, str(tmp / "extra_state.safetensors"))
        torch.save(opt.state_dict(), tmp / "optimizer.pt")
        # The inference weights: EMA swapped in for the save, then the raw weights back.
        raw = [p.detach().clone() for p in params]
        with torch.no_grad():
            if ema is not None:
                for p, e in zip(params, ema):
                    p.copy_(e.to(p.dtype))
            save_fn(accel.unwrap_model(module), tmp / "model")
            for p, r in zip(params, raw):
                p.copy_(r)
        (tmp / "state.json").write_text(json.dumps({"step": step, "loop": asdict(cfg), "stage_config": stage_config}, indent=1))
        shutil.rmtree(ck, ignore_errors=True)
        os.replace(tmp, ck)
        write_json_atomic(out_dir / "log.json", history, indent=None)
        for old in list_checkpoints(out_dir)[: -max(1, cfg.keep_ckpts)]:
            shutil.rmtree(old, ignore_errors=True)

    module.train()
    if resume is not None:
        torch.manual_seed(cfg.seed + step)  # fresh noise after a resume, not a replay
    batch_iter = batches(step) if callable(batches) else batches
    first_step = step
    sync = torch.cuda.synchronize if torch.cuda.is_available() else (lambda: None)
    split = {"data": 0.0, "forward": 0.0, "backward": 0.0}
    split_n = 0
    timing: dict[str, float] | None = None
    t_start = time.perf_counter()
    t_last, steps_since = t_start, 0
    last_ck: Path | None = resume
    while step < cfg.steps:
        measure = timing is None and step > first_step  # skip the first (warm-up) step
        t0 = time.perf_counter()
        batch = next(batch_iter)
        if measure:
            sync()
        t1 = time.perf_counter()
        with accel.accumulate(module):
            loss, logs = loss_fn(batch, step)
            loss_value = float(loss.detach())
            t2 = time.perf_counter()
            if not math.isfinite(loss_value):
                raise FloatingPointError(f"loss became {loss_value} at step {step}; lower --lr or check the data")
            accel.backward(loss)
            if cfg.grad_clip > 0:
                accel.clip_grad_norm_(params, cfg.grad_clip)
            opt.step()
            sched.step()
            opt.zero_grad(set_to_none=True)
        step += 1
        steps_since += 1
        if ema is not None:
            d = min(cfg.ema_decay, (1 + step) / (10 + step))
            with torch.no_grad():
                torch._foreach_lerp_(ema, [p.detach().float() for p in params], 1 - d)
        if measure:
            sync()
        now = time.perf_counter()
        step_timing = None
        if measure:
            split["data"] += t1 - t0
            split["forward"] += t2 - t1
            split["backward"] += now - t2
            split_n += 1
            if split_n >= TIMING_STEPS or step == cfg.steps:
                timing = {k: v / split_n for k, v in split.items()}
                timing["steps"] = split_n
                step_timing = timing
                total = sum(timing[k] for k in ("data", "forward", "backward"))
                log.info(
                    "step time %.3f s: data %.0f%%, forward %.0f%%, backward+optimiser %.0f%% (mean of %d steps)",
                    total, *(100 * timing[k] / max(total, 1e-12) for k in ("data", "forward", "backward")), split_n,
                )
        sps = steps_since / max(now - t_last, 1e-9)
        if steps_since >= 10 or now - t_last > 30:
            t_last, steps_since = now, 0
        entry = StepLog(step, loss_value, sps, sps * batch_size, sched.get_last_lr()[0], logs, step_timing)
        history.append({"step": step, "loss": entry.loss, "lr": entry.lr, "steps_per_s": round(sps, 4), **logs})
        if on_step is not None:
            on_step(entry)
        out_of_time = cfg.time_limit_s > 0 and now - t_start > cfg.time_limit_s
        if step % cfg.ckpt_every == 0 or step == cfg.steps or out_of_time:
            last_ck = checkpoint()
        if out_of_time:
            log.info("time limit reached at step %d", step)
            break
    if last_ck is None or not last_ck.name.endswith(f"{step:09d}"):
        last_ck = checkpoint()
    seconds = time.perf_counter() - t_start
    ran = step - first_step
    if ran > 0:
        summary = {
            "steps_run": ran,
            "first_step": first_step,
            "last_step": step,
            "seconds": round(seconds, 3),
            "steps_per_s": ran / max(seconds, 1e-9),
            "samples_per_s": ran * batch_size / max(seconds, 1e-9),
            "batch_size": batch_size,
            "timing_s": timing,
            "device": str(accel.device),
        }
        if accel.is_main_process:
            write_json_atomic(out_dir / "summary.json", summary, indent=None)
    return last_ck
