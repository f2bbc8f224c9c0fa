"""`x2video train fill`: fit the learned keyframe fill (`x2video.base.learned`, tier 1 of the fill) to path-traced shots.

Data: shot folders with rgb on every frame (the Cycles factory's multi-layer EXR shots, `x2video dataset make
--renderer cycles`: Combined, the G-buffers, depth, Emit + Env, cameras.json) under DATA/train/, validated on
DATA/val/ (else DATA/test/). Each step trains on random crops of a pool of samples (`fill_data`: random N, random
keyframe phase, a frame between held out as the target); a few samples of the pool are replaced every step, since
making one (two reprojections) costs more than the network's step.

Loss on the frame between, in the rgb's units: L1 of the display images (`tonemap`, what PSNR measures) plus
`log_weight` x L1 in log1p space relative to the frame's light level (keeps highlights above display white).
Validation: full frames of fixed samples of the held-out shots, the learned fill's PSNR beside the classical
fill's. Resumable (OUT/checkpoint.pt), with a wall-clock budget; the best weights go to OUT/best/ as fp16
fill.safetensors + fill.json, the last to OUT/last/.
"""
from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch
from torch.nn import functional as F

from x2video.base.learned import N_PLANES
from x2video.io.atomic import atomic_path, write_json_atomic
from x2video.model import fill_net as FN
from x2video.shot import Shot
from x2video.train import fill_data as D
from x2video.train.small_nets import optimiser_step, over_budget, tonemap_t, warm_cosine

log = logging.getLogger(__name__)


@dataclass
class FillTrainConfig:
    """What `x2video train fill` does; field docstrings are its help."""

    steps: int = 6000
    """Optimiser steps (a run stops earlier at --minutes)."""
    minutes: float = 0.0
    """Wall-clock limit of the training loop in minutes (0: none; reading new shots into the cache comes before it); a
    checkpoint and a validation are written when it is reached."""
    batch: int = 8
    """Crops per step."""
    crop: int = 128
    """Side of the square random crops (the frame's side where smaller)."""
    pool: int = 48
    """Frames between held in memory to crop from."""
    refresh: int = 2
    """Samples of the pool replaced by new ones every step."""
    every: tuple[int, ...] = (2, 4, 8, 16)
    """Keyframe spacings N to draw from (those a shot is long enough for)."""
    irradiance_dropout: float = 0.5
    """Probability that a sample's irradiance is hidden (keyframe shots may have none)."""
    flow_p: float = 0.15
    """Probability that a sample's depth and cameras are hidden, so the fill carries its pixels by G-buffer flow."""
    lr: float = 1e-3
    """AdamW peak learning rate (cosine decay to 5 % over `steps`, 100 warm-up steps)."""
    log_weight: float = 0.25
    """Weight of the log1p-space L1 beside the display-space L1."""
    val_every: int = 250
    """Validate on the held-out shots (full frames) every this many steps."""
    val_frames: int = 24
    """Fixed samples of the held-out shots that validation scores."""
    ckpt_every: int = 250
    """Write a resumable checkpoint every this many steps."""
    seed: int = 0
    """Seed of the samples and the initial weights."""
    widths: tuple[int, ...] = field(default_factory=lambda: (16, 32, 64))
    """Channels per level of the network, finest first."""


def predict(net: FN.FillNet, b: dict[str, torch.Tensor]) -> torch.Tensor:
    """rgb (N, 3, H, W) of a batch: the classical shading corrected by the net, modulated by albedo and emission."""
    s = FN.corrected(b["shading"], b["level"], FN.correction(net, b["x"]))
    return (s * b["albedo"] + b["emission"]).clamp_min(0)


def loss_fn(pred: torch.Tensor, target: torch.Tensor, level: torch.Tensor, log_weight: float) -> torch.Tensor:
    display = F.l1_loss(tonemap_t(pred), tonemap_t(target))
    return display + log_weight * F.l1_loss(torch.log1p(pred / level), torch.log1p(target.clamp_min(0) / level))


def _batch(arrays: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    return {k: torch.from_numpy(np.ascontiguousarray(v, np.float32)) for k, v in arrays.items()}


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return 10 * math.log10(1.0 / max(float(F.mse_loss(tonemap_t(a), tonemap_t(b))), 1e-12))


@torch.no_grad()
def validate(net: FN.FillNet, samples: Sequence[D.Sample]) -> dict:
    """Mean display PSNR over full frames of the learned fill and of the classical fill, and per N."""
    net.eval()
    rows = []
    for s in samples:
        b = _batch({k: getattr(s, k)[None] for k in ("x", "shading", "albedo", "emission", "target")})
        b["level"] = torch.full((1, 1, 1, 1), s.level)
        classical = (b["shading"] * b["albedo"] + b["emission"]).clamp_min(0)
        rows.append((s.spec.k1 - s.spec.k0, _psnr(predict(net, b), b["target"]), _psnr(classical, b["target"])))
    net.train()
    by_n = {str(n): {"psnr": float(np.mean([r[1] for r in rows if r[0] == n])),
                     "psnr_classical": float(np.mean([r[2] for r in rows if r[0] == n]))} for n in sorted({r[0] for r in rows})}
    return {"psnr": float(np.mean([r[1] for r in rows])), "psnr_classical": float(np.mean([r[2] for r in rows])),
            "frames": len(rows), "by_every": by_n}


def val_samples(shots: Sequence[Shot], cfg: FillTrainConfig) -> list[D.Sample]:
    """`cfg.val_frames` fixed samples of the held-out shots (the same every validation and every resumed run)."""
    if not shots:
        return []
    rng = np.random.default_rng([cfg.seed, 7919])
    return [D.make_sample(shots, D.draw(rng, shots, cfg.every, cfg.irradiance_dropout, 0.0)) for _ in range(cfg.val_frames)]


def train(train_shots: Sequence[Shot], val_shots: Sequence[Shot], out: Path, cfg: FillTrainConfig, *,
          trained_on: dict | None = None, progress: Callable[[dict], None] | None = None) -> dict:
    """Train (or resume from OUT/checkpoint.pt) the fill network on `train_shots`; returns the summary."""
    if not train_shots:
        raise ValueError("no shots to train the learned fill on")
    for i, s in enumerate([*train_shots, *val_shots]):
        D.check_shot(s, s.info.source or f"shot {i}")
    for name, v in (("irradiance_dropout", cfg.irradiance_dropout), ("flow_p", cfg.flow_p)):
        if not 0 <= v <= 1:
            raise ValueError(f"{name} must lie in [0, 1], got {v}")
    if cfg.steps < 1 or cfg.batch < 1 or cfg.pool < 1:
        raise ValueError("steps, batch and pool must be at least 1")
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    net = FN.FillNet(FN.FillNetConfig(in_channels=N_PLANES, widths=tuple(cfg.widths)))
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=1e-4)
    step, best, history = 0, -math.inf, []
    ck = out / "checkpoint.pt"
    if ck.is_file():
        state = torch.load(ck, map_location="cpu", weights_only=False)
        net.load_state_dict(state["net"])
        opt.load_state_dict(state["opt"])
        step, best, history = int(state["step"]), float(state["best"]), list(state.get("history", []))
        log.info("resuming %s at step %d", out, step)
    rng = np.random.default_rng([cfg.seed, step])
    t0 = time.perf_counter()
    val = val_samples(val_shots, cfg)

    def sample() -> D.Sample:
        return D.make_sample(train_shots, D.draw(rng, train_shots, cfg.every, cfg.irradiance_dropout, cfg.flow_p))

    pool = [sample() for _ in range(cfg.pool)]
    facts = {"trained_on": trained_on or {}, "training": asdict(cfg)}

    def checkpoint() -> None:
        with atomic_path(ck) as tmp:
            torch.save({"net": net.state_dict(), "opt": opt.state_dict(), "step": step, "best": best, "history": history}, tmp)

    net.train()
    loss = torch.zeros(())
    while step < cfg.steps:
        for _ in range(min(cfg.refresh, len(pool))):
            pool[int(rng.integers(len(pool)))] = sample()
        for g in opt.param_groups:
            g["lr"] = cfg.lr * warm_cosine(step, cfg.steps)
        b = _batch(D.crops(pool, rng, cfg.batch, cfg.crop))
        loss = loss_fn(predict(net, b), b["target"], b["level"], cfg.log_weight)
        optimiser_step(net, opt, loss)
        step += 1
        over = over_budget(t0, cfg.minutes)
        if step % cfg.val_every == 0 or step == cfg.steps or over:
            v = validate(net, val) if val else {}
            v.update(step=step, loss=float(loss.detach()), seconds=round(time.perf_counter() - t0, 1))
            history.append(v)
            if progress is not None:
                progress(v)
            if val and v["psnr"] > best:
                best = v["psnr"]
                FN.save(net, out / "best", {**facts, "step": step, "val": v})
        if step % cfg.ckpt_every == 0 or over:
            checkpoint()
        if over:
            break
    checkpoint()
    seconds = round(time.perf_counter() - t0, 1)
    last = history[-1] if history else {}
    FN.save(net, out / "last", {**facts, "step": step, "val": last})
    if not val:  # nothing held out: the last weights are the ones to ship
        FN.save(net, out / "best", {**facts, "step": step, "val": last})
    summary = {**facts, "steps": step, "seconds": seconds, "best_val_psnr": best if val else None,
               "train_shots": len(train_shots), "val_frames": len(val), "history": history}
    prev = json.loads((out / "results.json").read_text()) if (out / "results.json").is_file() else {}
    write_json_atomic(out / "results.json", {**prev, "fill": summary})
    return summary


def train_folder(data: Path, out: Path, cfg: FillTrainConfig, *, threads: int = 2,
                 progress: Callable[[dict], None] | None = None) -> dict:
    """`train` on the shot folders of DATA/train, validated on DATA/val (else DATA/test), read once into OUT/cache."""
    from x2video.io.dataset import shot_dirs

    torch.set_num_threads(max(1, threads))
    cache = out / "cache"
    train_dirs = shot_dirs(data, "train")
    if not train_dirs:
        raise ValueError(f"{data}: no finished shots in train/ (make them with `x2video dataset make --renderer cycles`)")
    val_split = "val" if shot_dirs(data, "val") else "test"
    shots = [D.CachedShot(D.cache_shot(p, cache)) for p in train_dirs]
    held = [D.CachedShot(D.cache_shot(p, cache)) for p in shot_dirs(data, val_split)]
    h, w = shots[0].size
    on = {"data": data.name, "train_shots": len(shots), "train_frames": sum(s.num_frames for s in shots),
          "val_split": val_split, "val_shots": len(held), "size": f"{w}x{h}", "threads": max(1, threads)}
    return train(shots, held, out, cfg, trained_on=on, progress=progress)
