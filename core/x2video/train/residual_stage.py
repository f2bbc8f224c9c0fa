"""`x2video train residual`: fit the tier-1 network (`x2video.model.residual`) to path-traced shots.

Data: shot folders any loader reads (Cycles multi-layer EXR shots from `x2video dataset make
--renderer cycles` go through the user's Blender loader) holding the five channels and the
ground-truth ``rgb``. Irradiance is exposure-normalised once per shot by the loader; the target
is scaled by the same factor, so the net works at one exposure and its output divided by the
factor is in the input's units. Each shot's frames are read once into a float16 cache file.

Loss, on random crops with horizontal flips (the normal's x flips too): L1 of the display images
(`tonemap`, what PSNR measures) plus a quarter of L1 in log1p space (keeps highlights above
display white). Channel dropout is off: tier 1 serves frames with all channels (tier 2, the
diffusion sampler, generates the rest). Checkpoints every `ckpt_every` steps; a run resumes from
its last one; the weights with the best validation PSNR are kept in `best/`.
"""
from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch.nn import functional as F

from x2video.channels import INTRINSIC
from x2video.io.atomic import atomic_path, write_json_atomic
from x2video.io.dataset import shot_dirs
from x2video.model import residual as R
from x2video.model import screen_space as SS
from x2video.train.small_nets import optimiser_step, over_budget, tonemap_t, warm_cosine

log = logging.getLogger(__name__)


@dataclass
class ResidualTrainConfig:
    """What `x2video train residual` does; field docstrings are its help."""

    steps: int = 3000
    """Optimiser steps (a run stops earlier at --minutes)."""
    minutes: float = 0.0
    """Wall-clock limit in minutes (0: none); a checkpoint is written when it is reached."""
    batch: int = 8
    """Crops per step."""
    crop: int = 128
    """Side of the square random crops (a multiple of the net's factor)."""
    lr: float = 2e-3
    """AdamW peak learning rate (cosine decay to 5 % over `steps`, 100 warm-up steps)."""
    log_weight: float = 0.25
    """Weight of the log1p-space L1 beside the display-space L1."""
    l2_weight: float = 0.0
    """Weight of a display-space squared error beside the L1s: where the channels leave the light uncertain (what a
    window or glass shows) L1 learns the likeliest value and L2 the mean, which is what PSNR rewards."""
    noisy_p: float = 0.3
    """Probability that a crop's irradiance is the sampled (noisy) one the shot keeps beside the denoised one."""
    exposure_aug: float = 2.0
    """Each crop's light is scaled by a random gain in [1/a, a] (irradiance and target alike), so the net does
    not key on the level the exposure normaliser happened to choose for a shot (1: off)."""
    format_aug: float = 0.3
    """Probability that a crop's channels come as other tools write them: 8-bit sRGB albedo, 8-bit normals,
    roughness and metallic, and half the time an 8-bit sRGB irradiance (scaled to its 99th percentile), as an
    archviz PNG export holds them (the loaders read those formats; `as_8bit`)."""
    irradiance_dropout: float = 0.0
    """Probability that a crop's irradiance is dropped (its planes and the formula's zeroed, its present flag 0).
    1 trains a net for shots without an irradiance pass, validated so (`residual_noirr`); between 0 and 1, one
    net for both, validated with every channel."""
    val_every: int = 250
    """Validate on the held-out shots (full frames) every this many steps."""
    ckpt_every: int = 250
    """Write a resumable checkpoint every this many steps."""
    seed: int = 0
    """Seed of the crops and the initial weights."""
    widths: tuple[int, ...] = field(default_factory=lambda: R.ResidualConfig().widths)
    """Channels per level of the net, finest first."""
    hints: bool = False
    """Feed the net the screen-space hints (`x2video.model.screen_space`: reflections marched through the shots'
    depth, the split-sum specular colour, N.V, the reflected direction); a shot without depth gets them without
    the reflections."""


def cache_shot(shot_dir: Path, cache_dir: Path, hints: bool = False) -> Path:
    """Read a shot once into `cache_dir/<name>.npz`: features (T, C, H, W), target (T, 3, H, W) float16, scale;
    with `hints` the features carry the screen-space hint planes (a cache of other planes is an error)."""
    from x2video.io import load_shot

    out = cache_dir / f"{shot_dir.parent.name}_{shot_dir.name}.npz"
    if out.is_file():
        return out
    shot = load_shot(shot_dir)
    missing = [c for c in (*INTRINSIC, "rgb") if c not in shot.info.channels]
    if missing:
        raise ValueError(f"{shot_dir}: lacks {', '.join(missing)}; tier-1 training needs the five channels and rgb")
    s = float(shot.info.irradiance_scale)
    files = sorted(shot_dir.glob("*.exr"))
    xs, ys, noisy = [], [], []
    has_depth = "depth" in shot.info.channels
    for t in range(shot.num_frames):
        fr = shot.frame(t)
        ch = {k: fr[k] for k in INTRINSIC}
        view = dict(hints=True, depth=fr["depth"] if has_depth else None, fov_y_deg=_fov(shot, t)) if hints else {}
        x, _ = R.features(ch, **view)
        xs.append(x.astype(np.float16))
        ys.append((np.asarray(fr["rgb"], np.float32) * s).transpose(2, 0, 1).astype(np.float16))
        raw = noisy_irradiance(files[t]) if len(files) == shot.num_frames else None
        if raw is not None:
            xn, _ = R.features({**ch, "irradiance": raw * s})  # (the noisy planes are base planes: no hints needed)
            noisy.append(xn[NOISY_PLANES].astype(np.float16))
    cache_dir.mkdir(parents=True, exist_ok=True)
    extra = {"noisy": np.stack(noisy)} if len(noisy) == len(xs) else {}
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, x=np.stack(xs), y=np.stack(ys), scale=np.float32(s), **extra)
    return out


#: input planes that change when the irradiance is the sampled (noisy) one: log irradiance and log formula
NOISY_PLANES = slice(8, 14)
#: the hint planes that hold light (the log formula a reflected ray meets) and the reflected direction's x
SSR_PLANES = slice(R.BASE_PLANES + SS.SSR_LOG.start, R.BASE_PLANES + SS.SSR_LOG.stop)
REFLECT_X_PLANE = R.BASE_PLANES + SS.REFLECT_X


def _fov(shot, t: int) -> float | None:
    poses = shot.info.poses
    return None if poses is None or poses[t] is None else poses[t].fov_y_deg


def noisy_irradiance(frame_file: Path) -> np.ndarray | None:
    """(H, W, 3) NoisyDiffDir + NoisyDiffInd of a Cycles frame from `x2video.cycles.passes.compositor_output`
    (the light passes as sampled, before denoising), or None when the file has none."""
    from x2video.io.image import read_image, read_spec

    names = set(read_spec(frame_file).channelnames)
    comps = {p: [f"{p}.{c}" for c in "RGB"] for p in ("NoisyDiffDir", "NoisyDiffInd")}
    if not all(c in names for cs in comps.values() for c in cs):
        return None
    img = read_image(frame_file, channels=[c for cs in comps.values() for c in cs])  # those 6 of the frame's ~70
    parts = [img.stack(cs) for cs in comps.values()]
    return np.nan_to_num(parts[0] + parts[1], nan=0.0, posinf=0.0, neginf=0.0).clip(0, None).astype(np.float32)


class Frames:
    """All cached frames of some shots in memory (float16), for crops and full-frame validation; with
    `noisy_p` > 0 a crop takes the frame's sampled (noisy) irradiance instead of the denoised one with
    that probability, where the shot has it (noise augmentation: users' passes are often not denoised)."""

    def __init__(self, files: list[Path], noisy_p: float = 0.0, exposure_aug: float = 1.0, irradiance_dropout: float = 0.0,
                 format_aug: float = 0.0):
        self.x, self.y, self.scale, self.shot, self.noisy = [], [], [], [], []
        self.noisy_p = noisy_p
        self.format_aug = format_aug
        self.irradiance_dropout = irradiance_dropout
        if exposure_aug < 1:
            raise ValueError(f"exposure_aug must be >= 1 (a gain range [1/a, a]), got {exposure_aug}")
        self.exposure_aug = exposure_aug
        for i, f in enumerate(files):
            d = np.load(f)
            # each d[key] reads and decompresses the whole array again: once per file, then views per frame (indexing
            # d["x"][t] per frame kept a full copy of the shot alive per frame: 22 GB for 2,400 frames of 20-frame clips)
            x, y, noisy, scale = d["x"], d["y"], d["noisy"] if "noisy" in d.files else None, float(d["scale"])
            for t in range(x.shape[0]):
                self.x.append(x[t])
                self.y.append(y[t])
                self.noisy.append(noisy[t] if noisy is not None else None)
                self.scale.append(scale)
                self.shot.append(i)
        if not self.x:
            raise ValueError("no frames to train on")

    def __len__(self) -> int:
        return len(self.x)

    def crops(self, rng: np.random.Generator, n: int, size: int) -> tuple[torch.Tensor, torch.Tensor]:
        xs, ys = [], []
        for _ in range(n):
            i = int(rng.integers(len(self.x)))
            x, y = self.x[i], self.y[i]
            h, w = x.shape[1:]
            s = min(size, h, w)
            r, c = int(rng.integers(h - s + 1)), int(rng.integers(w - s + 1))
            x, y = x[:, r:r + s, c:c + s].astype(np.float32), y[:, r:r + s, c:c + s].astype(np.float32)
            if self.noisy[i] is not None and rng.random() < self.noisy_p:
                x[NOISY_PLANES] = self.noisy[i][:, r:r + s, c:c + s]
            if self.exposure_aug > 1:  # the same scene under a brighter or dimmer light: log planes and target alike
                g = float(np.exp(rng.uniform(-1, 1) * np.log(self.exposure_aug)))
                x[NOISY_PLANES] = np.log1p(g * np.expm1(x[NOISY_PLANES]))
                if x.shape[0] > R.BASE_PLANES:
                    x[SSR_PLANES] = np.log1p(g * np.expm1(x[SSR_PLANES]))
                y = y * g
            if self.format_aug > 0 and rng.random() < self.format_aug:
                as_8bit(x, irradiance=bool(rng.random() < 0.5))
            if self.irradiance_dropout > 0 and rng.random() < self.irradiance_dropout:
                drop_irradiance(x)
            if rng.random() < 0.5:  # mirror left-right: the camera-space normal's x changes sign
                x, y = x[:, :, ::-1].copy(), y[:, :, ::-1].copy()
                x[3] = -x[3]
                if x.shape[0] > R.BASE_PLANES:  # so does the reflected direction's
                    x[REFLECT_X_PLANE] = -x[REFLECT_X_PLANE]
            xs.append(x)
            ys.append(y)
        return torch.from_numpy(np.stack(xs)), torch.from_numpy(np.stack(ys))


def _srgb8(v: np.ndarray) -> np.ndarray:
    """Linear [0, 1] -> through an 8-bit sRGB code value -> linear (what a PNG round trip does)."""
    from x2video.channels import linear_to_srgb, srgb_to_linear

    return srgb_to_linear(np.round(linear_to_srgb(np.clip(v, 0, 1)) * 255) / 255).astype(np.float32)


def as_8bit(x: np.ndarray, irradiance: bool = False) -> None:
    """In place: features (C, H, W) as `residual.features` makes them from 8-bit PNG channels: sRGB albedo, normals
    as (n + 1) / 2 code values (renormalised), roughness and metallic in 1/255 steps; with `irradiance`, an sRGB
    8-bit irradiance scaled so its 99th percentile is white (clipped above), back in the crop's units. The log
    formula follows the quantised albedo and irradiance."""
    x[0:3] = _srgb8(x[0:3])
    n = np.round((x[3:6] * 0.5 + 0.5).clip(0, 1) * 255) / 255 * 2 - 1
    norm = np.linalg.norm(n, axis=0, keepdims=True)
    x[3:6] = np.where(norm > 0.5, n / np.maximum(norm, 1e-6), 0)
    x[6:8] = np.round(x[6:8].clip(0, 1) * 255) / 255
    ir = np.expm1(x[8:11].astype(np.float32))
    if irradiance:
        top = max(float(np.percentile(ir, 99)), 1e-6)
        ir = _srgb8(ir / top) * top
        x[8:11] = np.log1p(ir)
    x[11:14] = np.log1p(x[0:3] * ir)


def drop_irradiance(x: np.ndarray | torch.Tensor) -> None:
    """In place: features (C, H, W) or (N, C, H, W) as `residual.features` makes them with irradiance dropped."""
    x[..., NOISY_PLANES, :, :] = 0  # log irradiance and log formula (albedo x 0)
    if x.shape[-3] > R.BASE_PLANES:
        x[..., SSR_PLANES, :, :] = 0  # the formula the reflected rays meet
    x[..., R.PRESENT_PLANES.start + INTRINSIC.index("irradiance"), :, :] = 0


def loss_fn(pred: torch.Tensor, y: torch.Tensor, log_weight: float, l2_weight: float = 0.0) -> torch.Tensor:
    dp, dy = tonemap_t(pred), tonemap_t(y)
    loss = F.l1_loss(dp, dy) + log_weight * F.l1_loss(torch.log1p(pred), torch.log1p(y.clamp_min(0)))
    return loss + l2_weight * F.mse_loss(dp, dy) if l2_weight else loss


@torch.no_grad()
def validate(net: R.ResidualNet, frames: Frames, without_irradiance: bool = False) -> dict[str, float]:
    """Mean PSNR (display, in the input's units: prediction and target divided by the shot's scale)
    of the net (given every channel, or all but irradiance) and of the formula (albedo x irradiance,
    every channel) over every held-out frame."""
    net.eval()
    ps_net, ps_form, ps_kept = [], [], []
    for x, y, s in zip(frames.x, frames.y, frames.scale):
        xt = torch.from_numpy(x.astype(np.float32))[None]
        shading = torch.expm1(xt[:, R.FORMULA_PLANES])
        if without_irradiance:
            xt = xt.clone()
            drop_irradiance(xt)
        pred = R.apply(net, xt, torch.expm1(xt[:, R.FORMULA_PLANES]))
        unseen = torch.from_numpy(unseen_in(x))[None, None]
        kept = torch.where(unseen, shading, pred)  # what tier 1 renders by default: the formula where the channels hold no light
        gt = tonemap_t(torch.from_numpy(y.astype(np.float32))[None] / s)
        for v, acc in ((pred, ps_net), (shading, ps_form), (kept, ps_kept)):
            mse = float(F.mse_loss(tonemap_t(v / s), gt))
            acc.append(10 * math.log10(1.0 / max(mse, 1e-12)))
    net.train()
    return {"psnr": float(np.mean(ps_net)), "psnr_formula": float(np.mean(ps_form)), "psnr_kept": float(np.mean(ps_kept)),
            "frames": len(ps_net)}


def unseen_in(x: np.ndarray) -> np.ndarray:
    """(H, W) bool `residual.unseen_light` of the channels that features `x` (C, H, W) were made from."""
    f = x.astype(np.float32)
    ch = {"normal": f[3:6].transpose(1, 2, 0), "roughness": f[6][..., None], "metallic": f[7][..., None],
          "irradiance": np.expm1(f[8:11]).transpose(1, 2, 0)}
    m = R.unseen_light(ch)
    return np.zeros(x.shape[1:], bool) if m is None else m


def train(data: Path, out: Path, cfg: ResidualTrainConfig, *, threads: int = 2, progress: Callable[[dict], None] | None = None) -> dict:
    """Train (or resume) a tier-1 net on `data/train`, validated on `data/val` (else `data/test`); returns the summary."""
    torch.set_num_threads(max(1, threads))
    cache = out / "cache"
    train_files = [cache_shot(p, cache, cfg.hints) for p in shot_dirs(data, "train")]
    val_split = "val" if shot_dirs(data, "val") else "test"
    val_files = [cache_shot(p, cache, cfg.hints) for p in shot_dirs(data, val_split)]
    if not train_files:
        raise ValueError(f"{data}: no finished shots in train/ (make them with `x2video dataset make --renderer cycles`)")
    if not 0 <= cfg.irradiance_dropout <= 1:
        raise ValueError(f"irradiance_dropout must lie in [0, 1], got {cfg.irradiance_dropout}")
    tr = Frames(train_files, cfg.noisy_p, cfg.exposure_aug, cfg.irradiance_dropout, cfg.format_aug)
    va = Frames(val_files) if val_files else None
    torch.manual_seed(cfg.seed)
    net = R.ResidualNet(R.ResidualConfig(widths=tuple(cfg.widths), hints=cfg.hints))
    planes = tr.x[0].shape[0]
    if planes != net.cfg.in_channels:
        raise ValueError(f"{cache}: the cached shots have {planes} feature planes, a net with hints={cfg.hints} reads "
                         f"{net.cfg.in_channels}; remove the cache (or train into another --out)")
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=1e-4)
    step, best = 0, -1.0
    ck = out / "checkpoint.pt"
    if ck.is_file():
        state = torch.load(ck, map_location="cpu", weights_only=False)
        net.load_state_dict(state["net"])
        opt.load_state_dict(state["opt"])
        step, best = int(state["step"]), float(state.get("best", -1.0))
        log.info("resuming %s at step %d", out, step)
    rng = np.random.default_rng([cfg.seed, step])
    history: list[dict] = []
    t0, seconds = time.perf_counter(), 0.0
    summary = {"config": asdict(cfg), "train_frames": len(tr), "val_frames": len(va) if va else 0, "val_split": val_split}

    def checkpoint() -> None:
        with atomic_path(ck) as tmp:
            torch.save({"net": net.state_dict(), "opt": opt.state_dict(), "step": step, "best": best}, tmp)

    net.train()
    while step < cfg.steps:
        for g in opt.param_groups:
            g["lr"] = cfg.lr * warm_cosine(step, cfg.steps)
        x, y = tr.crops(rng, cfg.batch, cfg.crop)
        pred = R.apply(net, x, torch.expm1(x[:, R.FORMULA_PLANES]))
        loss = loss_fn(pred, y, cfg.log_weight, cfg.l2_weight)
        optimiser_step(net, opt, loss)
        step += 1
        over = over_budget(t0, cfg.minutes)
        if va is not None and (step % cfg.val_every == 0 or step == cfg.steps or over):
            v = validate(net, va, without_irradiance=cfg.irradiance_dropout >= 1)
            v.update(step=step, loss=float(loss.detach()), seconds=round(time.perf_counter() - t0, 1))
            history.append(v)
            if progress is not None:
                progress(v)
            if v["psnr"] > best:
                best = v["psnr"]
                R.save(net, out / "best", {"step": step, "val": v, "trained_on": str(data.name)})
        if step % cfg.ckpt_every == 0 or over:
            checkpoint()
        if over:
            break
    checkpoint()
    seconds = time.perf_counter() - t0
    R.save(net, out / "last", {"step": step})
    summary.update(steps=step, seconds=round(seconds, 1), best_val_psnr=best, history=history)
    prev = json.loads((out / "results.json").read_text()) if (out / "results.json").is_file() else {}
    write_json_atomic(out / "results.json", {**prev, "residual": summary})
    return summary
