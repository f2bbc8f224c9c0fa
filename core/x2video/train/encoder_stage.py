"""Encoder stage: distil the VAE's encoder, on the conditioning channels only, into a `ChannelEncoder`
(the same encoder without its mid-block attention, started from the VAE's weights).

The teacher is a finished model folder (or run). A pool of evenly spaced frames of the training
rooms is read once; each frame gives the five images `X2VideoModel.encode_frames` encodes:
albedo, normal, roughness, metallic and the classical shading prior (its full form, plus one
variant a dropped channel makes: no metallic, or no specular term). The teacher's posterior mode
of every image is computed once, on the whole frame (its mid-block attention sees the whole
frame, so a crop's latents would differ). The student starts from the teacher's own encoder weights
(all but the attention's) and is trained on whole frames to match them,
the error measured in the UNet's input units (each latent times its channel's latent scale).

The run's `model/` holds the teacher's own parts unchanged (config, unet, vae, lcm_unet) plus
`channel_encoder.safetensors`, so `x2video train ship --model RUN` ships the teacher with it and
`--channel-encoder distilled` uses it. results.json gets the held-out error per channel:
RMSE in scaled latent units, the squared error relative to the latents' variance and the error's
norm relative to theirs, for the trained student and for where it started.
"""
from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np
import torch
from safetensors.torch import load_file

from x2video.channels import INTRINSIC, VAE_ENCODED
from x2video.model.channel_encoder import ChannelEncoder
from x2video.model.checkpoint import PARTS, load_into, save_checkpoint
from x2video.model.config import ModelConfig
from x2video.model.shading import classical_shading
from x2video.model.vae import encode_mode, to_vae_range
from x2video.shot import Shot
from x2video.train.config import EncoderStageConfig
from x2video.train.data import even_frames, read_frame
from x2video.train.loop import LoopConfig, StepLog, process_index, train
from x2video.train.runs import load_vae, model_dir, write_results

log = logging.getLogger(__name__)

#: the images the student learns, and the latent scale each is multiplied by in the UNet's input
IMAGES = {"albedo": "albedo", "normal": "normal", "roughness": "roughness", "metallic": "metallic", "shading": "rgb"}
_READ = INTRINSIC


def frame_images(channels: dict[str, np.ndarray], rng: np.random.Generator) -> list[tuple[str, np.ndarray]]:
    """The (kind, (H, W, 3) image in [-1, 1]) pairs of one frame: the four channels, the full shading
    prior and one variant with metallic or the specular inputs dropped (as a dropped channel makes it)."""
    out = [(c, to_vae_range(c, channels[c])) for c in VAE_ENCODED]
    out.append(("shading", to_vae_range("shading", classical_shading(channels))))
    variant = dict(channels)
    drop = ("metallic",), ("roughness",), ("normal", "metallic")
    for name in drop[int(rng.integers(len(drop)))]:
        variant[name] = None
    out.append(("shading", to_vae_range("shading", classical_shading(variant))))
    return out


def build_pool(shots: Sequence[Shot], frames_per_room: int, size: tuple[int, int] | None, seed: int) -> tuple[torch.Tensor, list[str]]:
    """(M, 3, H, W) float16 images of evenly spaced frames of every shot, and each image's kind."""
    rng = np.random.default_rng(seed)
    images, kinds, sizes = [], [], set()
    for shot in shots:
        for t in even_frames(shot, frames_per_room):
            for kind, img in frame_images(read_frame(shot, t, _READ, size), rng):
                images.append(img.astype(np.float16))
                kinds.append(kind)
                sizes.add(img.shape[:2])
    if not images:
        raise ValueError("encoder stage: no frames to train on")
    if len(sizes) != 1:
        raise ValueError(f"training frames differ in size {sorted(sizes)}; pass a common --size")
    return torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).contiguous(), kinds


@torch.no_grad()
def teacher_latents(vae, images: torch.Tensor, batch: int = 16) -> torch.Tensor:
    """(M, 4, h, w) float32 unscaled posterior mode of float16 `images`, encoded in float32 chunks."""
    return torch.cat([encode_mode(vae, images[i : i + batch].float(), batch) for i in range(0, images.shape[0], batch)])


def scale_vector(kinds: Sequence[str], cfg: ModelConfig) -> torch.Tensor:
    """(M, 1, 1, 1): each image's latent scale (the factor its latents enter the UNet with)."""
    return torch.tensor([cfg.latent_scales[IMAGES[k]] for k in kinds], dtype=torch.float32)[:, None, None, None]


def pool_batches(images: torch.Tensor, targets: torch.Tensor, scales: torch.Tensor, batch: int, seed: int) -> Callable[[int], Iterator[tuple]]:
    """A batch source for `train`: random whole images, their (unscaled) teacher latents and latent scales."""
    m = images.shape[0]

    def make(start: int) -> Iterator[tuple]:
        rng = np.random.default_rng([seed, start, process_index()])
        while True:
            idx = torch.from_numpy(rng.integers(m, size=batch))
            yield images[idx].float(), targets[idx], scales[idx]

    return make


@torch.no_grad()
def heldout_error(student: ChannelEncoder, images: torch.Tensor, targets: torch.Tensor, scales: torch.Tensor,
                  kinds: Sequence[str], batch: int = 32) -> dict[str, dict[str, float]]:
    """Per kind (and "all"): RMSE of the student's latents in scaled units, the squared error relative to
    the scaled teacher latents' variance (0: exact, 1: no better than their mean), and the error's norm
    relative to the latents' norm (|student - teacher| / |teacher|)."""
    student = student.eval()
    dev = next(student.parameters()).device
    pred = torch.cat([student(images[i : i + batch].float().to(dev)).cpu() for i in range(0, images.shape[0], batch)])
    err = (pred - targets) * scales
    out = {}
    for kind in [*IMAGES, "all"]:
        idx = [i for i, k in enumerate(kinds) if kind in (k, "all")]
        if not idx:
            continue
        e, t = err[idx], targets[idx] * scales[idx]
        out[kind] = {"rmse": float(e.pow(2).mean().sqrt()), "relative_mse": float(e.pow(2).mean() / t.var().clamp_min(1e-12)),
                     "relative_error": float(e.norm() / t.norm().clamp_min(1e-12)), "images": len(idx)}
    return out


def run_encoder_stage(
    teacher: str | Path,
    train_shots: Sequence[Shot],
    test_shots: Sequence[Shot],
    out_dir: str | Path,
    stage: EncoderStageConfig,
    loop: LoopConfig,
    on_step: Callable[[StepLog], None] | None = None,
) -> dict:
    """Train (or resume) the student in `out_dir`; returns and stores in results.json its held-out error."""
    out_dir = Path(out_dir)
    src = model_dir(teacher)
    cfg, vae = load_vae(src)
    if cfg.vae.latent_channels != 4:
        raise ValueError(f"{src}: the channel encoder is built for 4 latent channels, this VAE has {cfg.vae.latent_channels}")
    teacher_parts = {p: load_file(str(src / f"{p}.safetensors")) for p in PARTS
                     if p != "channel_encoder" and (src / f"{p}.safetensors").is_file()}
    if "unet" not in teacher_parts:
        raise FileNotFoundError(f"{src}: the teacher must be a whole model (unet.safetensors missing), not a VAE run")
    images, kinds = build_pool(train_shots, stage.pool_frames_per_room, stage.size, stage.seed)
    log.info("encoder pool: %d images of %s; encoding them with the teacher", len(kinds), tuple(images.shape[2:]))
    targets = teacher_latents(vae, images)
    scales = scale_vector(kinds, cfg)
    student = ChannelEncoder.from_vae(vae, cfg.vae)

    def loss_fn(batch: tuple, step: int) -> tuple[torch.Tensor, dict[str, float]]:
        x, z, s = (t.to(next(student.parameters()).device) for t in batch)
        loss = ((student(x) - z) * s).pow(2).mean()
        return loss, {}

    def save(module: torch.nn.Module, d: Path) -> None:
        save_checkpoint(d, cfg, {**teacher_parts, "channel_encoder": module})

    ck = train(
        module=student,
        loss_fn=loss_fn,
        batches=pool_batches(images, targets, scales, stage.batch, stage.seed),
        save_fn=save,
        out_dir=out_dir,
        cfg=loop,
        stage_config={"stage": "encoder", "teacher": str(src.resolve()), **dataclasses.asdict(stage)},
        batch_size=stage.batch,
        on_step=on_step,
    )
    result: dict = {"checkpoint": str(ck), "model": str(ck / "model"), "step": int(ck.name.split("-")[-1]), "teacher": str(src.resolve())}
    if test_shots and process_index() == 0:
        final = ChannelEncoder(cfg.vae)
        load_into(final, ck / "model" / "channel_encoder.safetensors", "channel_encoder")
        t_images, t_kinds = build_pool(test_shots, stage.eval_frames_per_room, stage.size, stage.seed + 1)
        t_scales, t_targets = scale_vector(t_kinds, cfg), teacher_latents(vae, t_images)
        result["heldout"] = heldout_error(final, t_images, t_targets, t_scales, t_kinds)
        # where the fine-tuning started: the encoder without attention, before training
        result["heldout_untrained"] = heldout_error(ChannelEncoder.from_vae(vae, cfg.vae), t_images, t_targets, t_scales, t_kinds)
        result["heldout_rooms"] = len(test_shots)
        log.info("channel encoder held-out relative MSE: %s",
                 {k: round(v["relative_mse"], 4) for k, v in result["heldout"].items()})
    write_results(out_dir, "encoder", result)
    return result
