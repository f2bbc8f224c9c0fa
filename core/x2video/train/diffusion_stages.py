"""Image stage (the XRGB of our world) and video stage (paper Sec. Implementation) on the latent cache.

Image stage: a freshly initialised XRGB-layout image UNet, v-prediction, single frames,
channel dropout, A|M|R masks, global prompt, no reference. Video stage: the image UNet
converted to the video UNet (Hybrid Self-Attention alphas 0, new inputs zero), windows of
N=5 frames in keyframe or interpolation mode at level k (selecting the LoRA branches),
references with p ~ 0.5, local prompts in Masked Cross-Attention; all parameters trainable.
Both save `X2VideoModel` folders (`from_pretrained` loads `step-*/model/`).
"""
from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from diffusers import UNet2DConditionModel

from x2video.model.checkpoint import load_into, read_config, save_checkpoint
from x2video.model.config import ModelConfig, UNetConfig, preset
from x2video.model.hybrid_attention import REF_BRANCHES, temporal_branches
from x2video.model.unet import build_unet, convert_image_to_video, hybrid_processors
from x2video.train.batches import AugmentConfig, LatentData, image_batches, video_batches
from x2video.train.config import ImageStageConfig, VideoStageConfig
from x2video.train.diffusion import check_noise_shared, diffusion_batch, heldout_v_loss, noise_scheduler, v_loss
from x2video.train.loop import LoopConfig, StepLog, process_index, train
from x2video.train.runs import check_same_vae, load_vae, model_dir, write_results

log = logging.getLogger(__name__)


def zero_output_layer(unet: UNet2DConditionModel) -> None:
    """Zero the UNet's output convolution (weights and bias): an x0 head that predicts 0, i.e. for a
    residual model the classical shading, until training moves it (ControlNet's zero convolutions)."""
    with torch.no_grad():
        unet.conv_out.weight.zero_()
        if unet.conv_out.bias is not None:
            unet.conv_out.bias.zero_()


def with_cache_prior(cfg: ModelConfig, cache: Path, what: str) -> ModelConfig:
    """`cfg` with the prior the cache holds (`CacheInfo.prior`): a model trained on a tier-1 cache samples over tier 1's
    frames. A model continued from the other prior keeps its weights; its prior slot now holds the cache's."""
    from x2video.train.cache import read_info

    prior = read_info(cache).prior
    if cfg.shading_prior and prior != cfg.prior:
        log.info("%s: its prior slot held the %s prior; this cache's (and from now on the model's) is %s", what, cfg.prior, prior)
        return dataclasses.replace(cfg, prior=prior)
    return cfg


def _resume_fields(stage) -> dict:
    """The stage settings a resumed run must share (the held-out report size is free to change)."""
    d = dataclasses.asdict(stage)
    d.pop("heldout_batches", None)
    return d


def image_model_config(stage: ImageStageConfig, cache_cfg: ModelConfig) -> ModelConfig:
    """The preset's UNet with the cache's VAE, latent scales and text encoder; video=False."""
    cfg = preset(stage.preset)
    unet = cfg.unet
    if stage.unet_channels:
        widths = tuple(stage.unet_channels)
        k = len(widths)
        heads = tuple(min(8, w // 8) or 1 for w in widths)
        unet = UNetConfig(block_out_channels=widths, layers_per_block=unet.layers_per_block,
                          attention_levels=(False,) + (True,) * (k - 1), attention_heads=heads,
                          cross_attention_dim=unet.cross_attention_dim, norm_num_groups=min(unet.norm_num_groups, min(widths)),
                          use_linear_projection=unet.use_linear_projection)
    return dataclasses.replace(cfg, unet=unet, vae=cache_cfg.vae, text=cache_cfg.text, latent_scales=dict(cache_cfg.latent_scales),
                               video=False, shading_prior=stage.shading_prior, residual_prior=stage.shading_prior and stage.residual_prior,
                               prediction=stage.prediction or ("sample" if stage.shading_prior and stage.residual_prior else "v"))


def _heldout_split(cache: Path) -> str | None:
    """The cache split the held-out loss reads (`data.heldout_split`), or None when the cache has no rooms of it."""
    from x2video.train.cache import read_info
    from x2video.train.data import heldout_split

    splits = {r["split"] for r in read_info(cache).rooms}
    split = heldout_split(splits)
    return split if split in splits else None


def _heldout(unet: UNet2DConditionModel, cache: Path, cfg: ModelConfig, shading: bool, n: int, draw, noise_shared: float = 0.0) -> dict:
    """Held-out v-loss on the cache's validation split (its test split in a cache made without one,
    `data.heldout_split`; the result's "heldout_split" says which): all channels, and with the training augmentation."""
    split = _heldout_split(cache)
    if n <= 0 or split is None:
        return {}
    data = LatentData(cache, split, cfg.latent_scales, shading)
    out = {}
    for name, aug in (("full", AugmentConfig(channel_drop_p=0.0, prompt_drop_p=0.0, mask_p=0.0)), ("augmented", AugmentConfig())):
        rng = np.random.default_rng(1234)
        out[name] = heldout_v_loss(unet, [diffusion_batch(draw(data, rng, aug), cfg.residual_prior) for _ in range(n)], prediction=cfg.prediction,
                                   noise_shared=noise_shared)
    return out


def _run(unet: UNet2DConditionModel, cfg: ModelConfig, cache: Path, out_dir: Path, loop: LoopConfig, batch_size: int,
         batches, stage_config: dict, on_step: Callable[[StepLog], None] | None, key: str, heldout=None,
         lr_mult: Callable[[str], float] | None = None,
         trainable: Callable[[UNet2DConditionModel], list[torch.nn.Parameter]] | None = None, noise_shared: float = 0.0) -> dict:
    _, vae = load_vae(cache / "model")
    sched = noise_scheduler()
    unet.requires_grad_(True)
    if trainable is not None:  # the parameters it returns train; the rest are frozen
        keep = {id(p) for p in trainable(unet)}
        for p in unet.parameters():
            p.requires_grad_(id(p) in keep)
        n = sum(p.numel() for p in unet.parameters() if p.requires_grad)
        if n == 0:
            raise ValueError(f"{key} stage: no parameter of the UNet is selected for training")
        log.info("%s stage: training %d of %d parameters", key, n, sum(p.numel() for p in unet.parameters()))

    def loss_fn(b, step):
        return v_loss(unet, sched, diffusion_batch(b.to(next(unet.parameters()).device), cfg.residual_prior), cfg.prediction, noise_shared)

    def save(module: torch.nn.Module, d: Path) -> None:
        save_checkpoint(d, cfg, {"unet": module, "vae": vae})

    ck = train(module=unet, loss_fn=loss_fn, batches=batches, save_fn=save, out_dir=out_dir, cfg=loop,
               stage_config=stage_config, batch_size=batch_size, on_step=on_step, lr_mult=lr_mult)
    summary = (out_dir / "summary.json").read_text() if (out_dir / "summary.json").is_file() else "{}"
    import json

    result = {"checkpoint": str(ck), "model": str(ck / "model"), "step": int(ck.name.split("-")[-1]),
              "shading_prior": cfg.shading_prior, "residual_prior": cfg.residual_prior, "prediction": cfg.prediction, "speed": json.loads(summary)}
    if heldout is not None and process_index() == 0:
        ema = build_unet(cfg)
        load_into(ema, ck / "model" / "unet.safetensors", "unet")
        result["heldout_v_loss"] = heldout(ema.to(next(unet.parameters()).device))
        result["heldout_split"] = _heldout_split(cache)
        log.info("%s stage held-out v-loss: %s", key, result["heldout_v_loss"])
    write_results(out_dir, key, result)
    return result


def run_image_stage(cache: str | Path, out_dir: str | Path, stage: ImageStageConfig, loop: LoopConfig,
                    on_step: Callable[[StepLog], None] | None = None) -> dict:
    """Train (or resume) the image UNet on the cache's train split."""
    cache, out_dir = Path(cache), Path(out_dir)
    if stage.init:  # absolute, so a resumed run matches whatever folder it is started from
        stage = dataclasses.replace(stage, init=str(Path(stage.init).resolve()))
    cache_cfg = read_config(cache / "model")
    cfg = with_cache_prior(image_model_config(stage, cache_cfg), cache, "image model")
    # With the shading prior the image UNet takes 27 inputs (XRGB's 23 + the shading latent), so
    # prior on/off is compared at the image stage on the same budget and the winner carried forward.
    data = LatentData(cache, "train", cfg.latent_scales, shading_prior=cfg.shading_prior)
    torch.manual_seed(stage.seed)
    unet = build_unet(cfg)
    if stage.init:
        init_cfg = read_config(model_dir(stage.init))
        if init_cfg.video or init_cfg.unet != cfg.unet or init_cfg.shading_prior != cfg.shading_prior:
            raise ValueError(f"--init {stage.init}: not an image model of this stage's architecture (video={init_cfg.video}, "
                             f"shading_prior={init_cfg.shading_prior}, unet {init_cfg.unet.block_out_channels})")
        check_same_vae(init_cfg, cache_cfg, f"image model {stage.init}")
        load_into(unet, model_dir(stage.init) / "unet.safetensors", "unet")
        log.info("image UNet initialised from %s", model_dir(stage.init))
    if cfg.prediction == "sample" and (not stage.init or init_cfg.prediction != "sample"):
        zero_output_layer(unet)
        log.info("x0 head zero-initialised: the untrained residual model renders the classical shading")
    n = sum(p.numel() for p in unet.parameters())
    log.info("image UNet: %.2f M parameters, %d training frames", n / 1e6, data.num_rows)
    sc = {"stage": "image", **_resume_fields(stage), "model": cfg.to_dict(), "cache": str(cache.resolve())}
    def heldout(m):
        return _heldout(m, cache, cfg, cfg.shading_prior, stage.heldout_batches, lambda d, rng, aug: d.sample(rng, d.random_frames(rng, stage.batch), aug))

    return _run(unet, cfg, cache, out_dir, loop, stage.batch, image_batches(data, stage.batch, stage.augment, stage.seed, loop.workers), sc, on_step,
                "image", heldout)


def load_image_unet(init: str | Path) -> tuple[ModelConfig, UNet2DConditionModel]:
    d = model_dir(init)
    cfg = read_config(d)
    if cfg.video:
        raise ValueError(f"{d} holds a video model; --init wants the image stage's run or model")
    unet = build_unet(cfg)
    load_into(unet, d / "unet.safetensors", "unet")
    return cfg, unet


def run_video_stage(init: str | Path, cache: str | Path, out_dir: str | Path, stage: VideoStageConfig, loop: LoopConfig,
                    on_step: Callable[[StepLog], None] | None = None) -> dict:
    """Convert the image UNet of `init` to the video UNet and train it on windows of the cache."""
    cache, out_dir = Path(cache), Path(out_dir)
    init_cfg = read_config(model_dir(init))
    if stage.train_only not in ("all", "interp"):
        raise ValueError(f"train_only must be 'all' or 'interp', got {stage.train_only!r}")
    check_noise_shared(stage.noise_shared)
    if stage.train_only == "interp":
        if not init_cfg.video:
            raise ValueError(f"--train-only interp fine-tunes a trained video model; --init {init} holds an image model")
        if stage.window.interp_p != 1.0:
            raise ValueError(f"--train-only interp needs --interp-p 1 (got {stage.window.interp_p}): keyframe-mode "
                             "windows do not reach the interpolation branches")
    if init_cfg.video:
        # continue a video model (e.g. into the residual target): no conversion, the architecture is kept
        if stage.shading_prior is not None and stage.shading_prior != init_cfg.shading_prior:
            raise ValueError(f"--init {init} is a video model with shading_prior={init_cfg.shading_prior}; it cannot change")
        check_same_vae(init_cfg, read_config(cache / "model"), f"video model {init}")
        sp = init_cfg.shading_prior
        cfg = dataclasses.replace(init_cfg, residual_prior=sp and (stage.residual_prior if stage.residual_prior is not None else init_cfg.residual_prior),
                                  prediction=stage.prediction or init_cfg.prediction)
        unet = build_unet(cfg)
        load_into(unet, model_dir(init) / "unet.safetensors", "unet")
        if cfg.prediction == "sample" and init_cfg.prediction != "sample":
            zero_output_layer(unet)
            log.info("x0 head zero-initialised on the continued video model")
    else:
        img_cfg, image_unet = load_image_unet(init)
        check_same_vae(img_cfg, read_config(cache / "model"), f"image model {init}")
        sp = img_cfg.shading_prior if stage.shading_prior is None else stage.shading_prior
        res = img_cfg.residual_prior if stage.residual_prior is None else stage.residual_prior
        cfg = dataclasses.replace(img_cfg, video=True, shading_prior=sp, residual_prior=sp and res, prediction=stage.prediction or img_cfg.prediction)
        unet = convert_image_to_video(image_unet, cfg.hybrid, sp)
        if cfg.prediction == "sample" and img_cfg.prediction != "sample":
            zero_output_layer(unet)
    cfg = with_cache_prior(cfg, cache, f"video model {init}")
    data = LatentData(cache, "train", cfg.latent_scales, sp)
    log.info("video UNet: %.2f M parameters, %d training frames", sum(p.numel() for p in unet.parameters()) / 1e6, data.num_rows)
    sc = {"stage": "video", **_resume_fields(stage), "model": cfg.to_dict(), "cache": str(cache.resolve()),
          "init": str(model_dir(init).resolve())}
    batches = video_batches(data, stage.batch, stage.augment, stage.window, stage.seed, loop.workers)
    def draw(d, rng, aug):
        windows, mode, level, refs = d.random_windows(rng, stage.batch, stage.window)
        return d.sample(rng, windows, aug, mode=mode, level=level, ref_positions=refs)

    return _run(unet, cfg, cache, out_dir, loop, stage.batch * stage.window.frames, batches, sc, on_step, "video",
                lambda m: _heldout(m, cache, cfg, sp, stage.heldout_batches, draw, stage.noise_shared), alpha_lr(stage.alpha_lr_mult),
                interp_branch_parameters if stage.train_only == "interp" else None, stage.noise_shared)


def interp_branch_parameters(unet: UNet2DConditionModel) -> list[torch.nn.Parameter]:
    """Parameters only interpolation-mode windows use: in every Hybrid Self-Attention layer, the temporal
    LoRA branches after "key" (interp1..K) and the end-frame reference branch (r1)."""
    out: list[torch.nn.Parameter] = []
    for proc in hybrid_processors(unet).values():
        for branch in temporal_branches(proc.interp_levels)[1:]:
            out += proc.temp.lora[branch].parameters()
        out += proc.ref.lora[REF_BRANCHES[1]].parameters()
    return out


def alpha_lr(mult: float) -> Callable[[str], float]:
    """Learning-rate multiplier by parameter name: `mult` for the Hybrid Self-Attention alphas, 1 otherwise."""
    return lambda name: mult if name.rsplit(".", 1)[-1] in ("alpha_r", "alpha_t") else 1.0
