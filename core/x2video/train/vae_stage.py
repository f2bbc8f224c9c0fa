"""VAE stage: one `AutoencoderKL` for rgb, albedo, normal, roughness and metallic images of the training rooms.

Batches mix random crops of random frames of every channel, each mapped to the VAE's
[-1, 1] exactly as `x2video.model.vae.to_vae_range` maps it at inference. A pool of frames
is read into memory once, so a step never waits on disk. Loss: L1 reconstruction plus a tiny
KL term (SD's 1e-6 per pixel). At the end the reconstruction PSNR of full held-out frames
is measured per channel: it caps every figure downstream.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np
import torch
from diffusers import AutoencoderKL

from x2video.model.checkpoint import save_checkpoint
from x2video.model.vae import build_vae, encode_mode, to_vae_range
from x2video.shot import Shot
from x2video.train.config import VAEStageConfig
from x2video.train.data import even_frames, read_frame
from x2video.train.loop import LoopConfig, StepLog, process_index, train
from x2video.train.runs import write_results

log = logging.getLogger(__name__)

#: the images the VAE learns (its latents condition the UNet or are its target)
VAE_CHANNELS = ("rgb", "albedo", "normal", "roughness", "metallic")


def build_pool(shots: Sequence[Shot], frames_per_room: int, size: tuple[int, int] | None) -> dict[str, np.ndarray]:
    """name -> (M, H, W, 3) float16 images in [-1, 1] of evenly spaced frames of every shot."""
    pool: dict[str, list[np.ndarray]] = {c: [] for c in VAE_CHANNELS}
    sizes = set()
    for shot in shots:
        for t in even_frames(shot, frames_per_room):
            fr = read_frame(shot, t, VAE_CHANNELS, size)
            for c in VAE_CHANNELS:
                pool[c].append(to_vae_range(c, fr[c]).astype(np.float16))
                sizes.add(pool[c][-1].shape[:2])
    if len(sizes) != 1:
        raise ValueError(f"training frames differ in size {sorted(sizes)}; pass a common --size")
    return {c: np.stack(v) for c, v in pool.items()}


def crop_batches(pool: dict[str, np.ndarray], batch: int, crop: int, seed: int) -> Callable[[int], Iterator[torch.Tensor]]:
    """A batch source for `train`: (B, 3, crop, crop) float32 random crops, channel and frame random per sample."""
    names = list(pool)
    m, h, w, _ = pool[names[0]].shape
    if crop > h or crop > w:
        raise ValueError(f"--crop {crop} is larger than the {w}x{h} training frames")

    def make(start: int) -> Iterator[torch.Tensor]:
        rng = np.random.default_rng([seed, start, process_index()])
        while True:
            c = rng.integers(len(names), size=batch)
            f = rng.integers(m, size=batch)
            y = rng.integers(h - crop + 1, size=batch)
            x = rng.integers(w - crop + 1, size=batch)
            arr = np.stack([pool[names[ci]][fi, yi : yi + crop, xi : xi + crop] for ci, fi, yi, xi in zip(c, f, y, x)])
            yield torch.from_numpy(arr.astype(np.float32)).permute(0, 3, 1, 2).contiguous()  # (B, 3, crop, crop)

    return make


def vae_loss(vae: AutoencoderKL, x: torch.Tensor, kl_weight: float) -> tuple[torch.Tensor, dict[str, float]]:
    """L1 reconstruction of a posterior sample + kl_weight * KL per pixel; x (B, 3, H, W) in [-1, 1]."""
    post = vae.encode(x).latent_dist
    rec = vae.decode(post.sample()).sample  # (B, 3, H, W)
    l1 = (rec - x).abs().mean()
    kl = post.kl().mean() / x[0].numel()
    return l1 + kl_weight * kl, {"l1": float(l1.detach()), "kl": float(kl.detach())}


@torch.no_grad()
def reconstruction_psnr(vae: AutoencoderKL, shots: Sequence[Shot], frames_per_room: int, size: tuple[int, int] | None) -> dict[str, float]:
    """Mean PSNR (dB, on the [0, 1] display range of each channel's VAE image) of full held-out frames
    through encode (posterior mode) -> decode, per channel and over all channels."""
    vae = vae.eval()
    dev = next(vae.parameters()).device
    f = 2 ** (len(vae.config.block_out_channels) - 1)
    per: dict[str, list[float]] = {c: [] for c in VAE_CHANNELS}
    for shot in shots:
        for t in even_frames(shot, frames_per_room):
            fr = read_frame(shot, t, VAE_CHANNELS, size)
            for c in VAE_CHANNELS:
                img = to_vae_range(c, fr[c])
                if img.shape[0] % f or img.shape[1] % f:
                    raise ValueError(f"shot {shot.info.source!r}: frame size {img.shape[1]}x{img.shape[0]} is not a multiple of the VAE factor {f}")
                x = torch.from_numpy(img).permute(2, 0, 1)[None].to(dev)  # (1, 3, H, W)
                rec = vae.decode(encode_mode(vae, x)).sample.clamp(-1, 1)
                mse = float(((rec - x) / 2).pow(2).mean())
                per[c].append(10 * math.log10(1.0 / max(mse, 1e-12)))
    out = {c: float(np.mean(v)) for c, v in per.items() if v}
    if out:
        out["mean"] = float(np.mean(list(out.values())))
    return out


def run_vae_stage(
    train_shots: Sequence[Shot],
    test_shots: Sequence[Shot],
    out_dir: str | Path,
    stage: VAEStageConfig,
    loop: LoopConfig,
    on_step: Callable[[StepLog], None] | None = None,
) -> dict:
    """Train (or resume) the VAE in `out_dir`; returns and stores in results.json the held-out PSNR."""
    out_dir = Path(out_dir)
    cfg = stage.model_config()
    f = cfg.vae.downsample
    if stage.crop % f:
        raise ValueError(f"--crop {stage.crop} is not a multiple of the VAE factor {f}")
    pool = build_pool(train_shots, stage.pool_frames_per_room, stage.size)
    log.info("VAE pool: %d frames x %d channels of %s", len(pool["rgb"]), len(pool), pool["rgb"].shape[1:3])
    torch.manual_seed(stage.seed)
    vae = build_vae(cfg.vae)

    def save(module: torch.nn.Module, d: Path) -> None:
        save_checkpoint(d, cfg, {"vae": module})

    ck = train(
        module=vae,
        loss_fn=lambda x, step: vae_loss(vae, x.to(next(vae.parameters()).device), stage.kl_weight),
        batches=crop_batches(pool, stage.batch, stage.crop, stage.seed),
        save_fn=save,
        out_dir=out_dir,
        cfg=loop,
        stage_config={"stage": "vae", **dataclasses.asdict(stage), "model": cfg.to_dict()},
        batch_size=stage.batch,
        on_step=on_step,
    )
    from x2video.train.runs import load_vae

    _, ema_vae = load_vae(ck / "model")
    main = process_index() == 0
    psnr = reconstruction_psnr(ema_vae, test_shots, stage.eval_frames_per_room, stage.size) if test_shots and main else {}
    result = {"checkpoint": str(ck), "step": int(ck.name.split("-")[-1]), "latent_factor": f,
              "vae_channels": list(cfg.vae.block_out_channels), "heldout_psnr_db": psnr,
              "heldout_rooms": len(test_shots), "frames_per_room": stage.eval_frames_per_room}
    write_results(out_dir, "vae", result)
    log.info("VAE held-out reconstruction PSNR: %s", {k: round(v, 2) for k, v in psnr.items()})
    return result
