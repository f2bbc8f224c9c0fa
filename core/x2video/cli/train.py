"""`x2video train vae|cache|image|video|lcm|residual|difference|fill`: the training stages (issue 5), each resumable, with a progress bar."""
from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from typing import Callable

from x2video.cli.args import size_arg
from x2video.cli.train_small import register_small
from x2video.fields import add_fields, from_args
from x2video.train.config import (
    AugmentConfig,
    CacheStageConfig,
    EncoderStageConfig,
    ImageStageConfig,
    LCMStageConfig,
    LoopConfig,
    VAEStageConfig,
    VideoStageConfig,
    WindowConfig,
)

log = logging.getLogger(__name__)


#: a WxH size field reads as 'WxH' (`size_arg`), not as a frame range
_SIZE = {"size": {"type": size_arg, "metavar": "WxH"}}
#: today's flag names of the per-room frame counts
_POOL = {"pool_frames_per_room": "--pool-frames", "eval_frames_per_room": "--eval-frames"}
#: stage fields whose flag another group adds (--seed: the loop's) or that are whole configs of their own
_NOT_STAGE = ("seed", "augment", "window")


def _stage_args(p: argparse.ArgumentParser, cls: type, **kwargs) -> None:
    """The flags of a stage's own settings dataclass (`x2video.train.config`), one per field."""
    add_fields(p.add_argument_group(f"stage ({cls.__name__})"), cls, skip=_NOT_STAGE, **kwargs)


def _loop_args(p: argparse.ArgumentParser, steps: int, lr: float, ema: float = LoopConfig.ema_decay) -> None:
    """The optimisation flags (`LoopConfig`), with this stage's steps, learning rate and EMA decay."""
    g = p.add_argument_group("optimisation (resumes from the newest step-* checkpoint in --out)")
    add_fields(g, LoopConfig, skip=("time_limit_s",), defaults=LoopConfig(steps=steps, lr=lr, ema_decay=ema),
               aliases={"ema_decay": "--ema", "keep_ckpts": "--keep"})
    g.add_argument("--time-limit", type=float, default=LoopConfig.time_limit_s / 60,
                   help="stop with a checkpoint after this many minutes (0 = none)")
    g.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = torch's default; 1 is fastest on a busy machine)")


def _aug_args(p: argparse.ArgumentParser) -> None:
    """The conditioning augmentation flags (`AugmentConfig`)."""
    add_fields(p.add_argument_group("conditioning augmentation"), AugmentConfig,
               aliases={"channel_drop_p": "--channel-drop", "prompt_drop_p": "--prompt-drop"})


def _window_args(p: argparse.ArgumentParser) -> None:
    """The video window flags (`WindowConfig`)."""
    add_fields(p.add_argument_group("windows"), WindowConfig, aliases={"ref_p_key": "--ref-p"}, overrides={
        "ref_p_key": {"help": f"probability a window carries its reference frame(s) (default: {WindowConfig.ref_p_key:g})"},
        "ref_p_interp": {"default": None, "help": "the same for interpolation windows (default: --ref-p; at inference they always carry both)"}})


def _loop_cfg(a: argparse.Namespace) -> LoopConfig:
    if a.threads:
        import torch

        torch.set_num_threads(a.threads)
    if a.steps < 1:
        raise ValueError("--steps must be >= 1")
    return from_args(LoopConfig, a, time_limit_s=a.time_limit * 60)


def _aug(a: argparse.Namespace) -> AugmentConfig:
    aug = from_args(AugmentConfig, a)
    for flag, v in (("--channel-drop", aug.channel_drop_p), ("--prompt-drop", aug.prompt_drop_p), ("--mask-p", aug.mask_p),
                    ("--ref-shift-p", aug.ref_shift_p), ("--local-prompt-p", aug.local_prompt_p)):
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"{flag} must be a probability in [0, 1], got {v}")
    if aug.ref_shift_std < 0:
        raise ValueError(f"--ref-shift-std must be >= 0, got {aug.ref_shift_std}")
    return aug


def _window(a: argparse.Namespace) -> WindowConfig:
    for flag, v in (("--ref-p", a.ref_p_key), ("--ref-p-interp", a.ref_p_interp), ("--interp-p", a.interp_p),
                    ("--reverse-p", a.reverse_p), ("--short-p", a.short_p)):
        if v is not None and not 0.0 <= v <= 1.0:
            raise ValueError(f"{flag} must be a probability in [0, 1], got {v}")
    return from_args(WindowConfig, a, ref_p_interp=a.ref_p_key if a.ref_p_interp is None else a.ref_p_interp)


class Progress:
    """A tqdm bar fed by the loop's on_step callback; prints the step-time split once."""

    def __init__(self, total: int, desc: str) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=desc, unit="step", dynamic_ncols=True)
        self.t0 = time.perf_counter()

    def __call__(self, s) -> None:
        self.bar.n = s.step
        self.bar.set_postfix(loss=f"{s.loss:.4f}", steps_s=f"{s.steps_per_s:.2f}", samples_s=f"{s.samples_per_s:.1f}", refresh=False)
        self.bar.refresh()
        if s.timing:
            t = s.timing
            total = t["data"] + t["forward"] + t["backward"]
            self.bar.write(f"step time {total:.3f} s = data {t['data']:.3f} + forward {t['forward']:.3f} + backward/optimiser {t['backward']:.3f}")

    def close(self) -> None:
        self.bar.close()


def _run(desc: str, steps: int, fn: Callable) -> dict:
    bar = Progress(steps, desc)
    try:
        return fn(bar)
    finally:
        bar.close()


def _print_result(result: dict) -> None:
    from x2video.train.loop import process_index

    if process_index() == 0:  # one print under `accelerate launch` / torchrun
        print(json.dumps(result, indent=1))


# -- stages -------------------------------------------------------------------------
def cmd_vae(a: argparse.Namespace) -> int:
    from x2video.train.data import heldout_split, open_dataset
    from x2video.train.vae_stage import run_vae_stage

    loop = _loop_cfg(a)
    if loop.workers:
        raise ValueError("--workers applies to the image, video and lcm stages (the VAE stage crops from frames in memory)")
    ds = open_dataset(a.data)
    stage = from_args(VAEStageConfig, a)  # seed: --seed
    held = ds[heldout_split(ds)]
    _print_result(_run("vae", loop.steps, lambda bar: run_vae_stage(ds["train"], held, a.out, stage, loop, bar)))
    return 0


def _prior_net(stage: CacheStageConfig):
    """The tier-1 net (PyTorch) that makes a tier-1 prior cache, or None for the classical shading."""
    if stage.prior != "tier1":
        return None
    from x2video.model.residual import load as load_residual
    from x2video.weights import shipped_weights

    folder = Path(stage.residual) if stage.residual else shipped_weights()
    if folder is None or not (folder / "residual.safetensors").is_file():
        raise FileNotFoundError(f"{folder}: no residual.safetensors there; --prior tier1 needs a tier-1 net (--residual FOLDER)")
    return load_residual(folder).eval()


def cmd_cache(a: argparse.Namespace) -> int:
    from tqdm import tqdm

    from x2video.train.cache import build_cache
    from x2video.train.data import open_dataset
    from x2video.train.runs import load_vae

    if a.threads:
        import torch

        torch.set_num_threads(a.threads)
    ds = open_dataset(a.data, need_test=False)
    stage = from_args(CacheStageConfig, a)
    cfg, vae = load_vae(a.vae)
    total = sum(s.num_frames for v in ds.values() for s in v)
    bar = tqdm(total=total, desc="cache", unit="frame", dynamic_ncols=True)
    t0 = time.perf_counter()

    def progress(done: int, tot: int) -> None:
        bar.n = done
        bar.refresh()

    try:
        info = build_cache(ds, vae, cfg, a.out, size=stage.size, batch=stage.batch, progress=progress, prior_net=_prior_net(stage))
    finally:
        bar.close()
    secs = time.perf_counter() - t0
    rooms = {s: sum(1 for r in info.rooms if r["split"] == s) for s in ("train", "val", "test")}
    _print_result({"cache": str(a.out), "frames": total, "rooms": rooms, "size": info.size, "latent_size": info.latent_size,
                   "prompts": len(info.prompts), "seconds": round(secs, 1), "frames_per_s": round(total / max(secs, 1e-9), 2)})
    return 0


def cmd_image(a: argparse.Namespace) -> int:
    from x2video.train.diffusion_stages import run_image_stage

    loop = _loop_cfg(a)
    stage = from_args(ImageStageConfig, a, augment=_aug(a))
    _print_result(_run("image", loop.steps, lambda bar: run_image_stage(a.cache, a.out, stage, loop, bar)))
    return 0


def cmd_video(a: argparse.Namespace) -> int:
    from x2video.train.diffusion_stages import run_video_stage

    loop = _loop_cfg(a)
    stage = from_args(VideoStageConfig, a, augment=_aug(a), window=_window(a))
    _print_result(_run("video", loop.steps, lambda bar: run_video_stage(a.init, a.cache, a.out, stage, loop, bar)))
    return 0


def cmd_lcm(a: argparse.Namespace) -> int:
    from x2video.train.lcm_stage import run_lcm_stage

    loop = _loop_cfg(a)
    stage = from_args(LCMStageConfig, a, augment=_aug(a), window=_window(a))
    _print_result(_run("lcm", loop.steps, lambda bar: run_lcm_stage(a.teacher, a.cache, a.out, stage, loop, bar, student_init=a.student_init)))
    return 0


def cmd_encoder(a: argparse.Namespace) -> int:
    from x2video.eval.data import training_size
    from x2video.train.data import heldout_split, open_dataset
    from x2video.train.encoder_stage import run_encoder_stage
    from x2video.train.runs import model_dir

    loop = _loop_cfg(a)
    if loop.workers:
        raise ValueError("--workers applies to the image, video and lcm stages (the encoder stage trains on frames in memory)")
    ds = open_dataset(a.data)
    size = a.size or training_size(model_dir(a.teacher))
    stage = from_args(EncoderStageConfig, a, size=size)
    held = ds[heldout_split(ds)]
    _print_result(_run("encoder", loop.steps, lambda bar: run_encoder_stage(a.teacher, ds["train"], held, a.out, stage, loop, bar)))
    return 0


def cmd_ship(a: argparse.Namespace) -> int:
    """Write a trained model as the fp16 folder the CLI, editor and eval load by default."""
    from x2video.train.ship import ship

    _print_result(ship(a.model, a.out, image=a.image, size=a.size, runs=a.run, overwrite=a.overwrite,
                       keep_runs=a.keep_runs))
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("train", help="train the VAE, cache latents, train the image, video and LCM models, distil the channel encoder",
                              description="Training stages, in order: vae -> cache -> image -> video -> lcm (-> encoder). Each is resumable: "
                                          "run the same command again (with a larger --steps) to continue.")
    sub = p.add_subparsers(dest="stage", metavar="STAGE")
    sub.required = True

    s = sub.add_parser("vae", help="train the AutoencoderKL on rgb/albedo/normal/roughness/metallic crops")
    s.add_argument("--data", type=Path, required=True, help="data set folder with train/ and test/ rooms")
    s.add_argument("--out", type=Path, required=True, help="run folder")
    _stage_args(s, VAEStageConfig, aliases={"layers_per_block": "--vae-layers", **_POOL}, overrides=_SIZE)
    _loop_args(s, steps=2000, lr=2e-4)
    s.set_defaults(func=cmd_vae)

    s = sub.add_parser("cache", help="encode every frame of the data set once with the frozen VAE")
    s.add_argument("--data", type=Path, required=True, help="data set folder with train/ (and test/) rooms")
    s.add_argument("--vae", type=Path, required=True, help="VAE run folder (newest checkpoint) or model folder")
    s.add_argument("--out", type=Path, required=True, help="cache folder")
    _stage_args(s, CacheStageConfig, overrides=_SIZE)
    s.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = default)")
    s.set_defaults(func=cmd_cache)

    s = sub.add_parser("image", help="XRGB-style image UNet on cached latents")
    s.add_argument("--cache", type=Path, required=True)
    s.add_argument("--out", type=Path, required=True)
    _stage_args(s, ImageStageConfig)
    _aug_args(s)
    _loop_args(s, steps=2000, lr=1e-4)
    s.set_defaults(func=cmd_image)

    s = sub.add_parser("video", help="convert the image UNet to the video UNet and train it on windows")
    s.add_argument("--init", type=Path, required=True,
                   help="image run (newest checkpoint) or image model folder, converted; or a video run/model, continued")
    s.add_argument("--cache", type=Path, required=True)
    s.add_argument("--out", type=Path, required=True)
    _stage_args(s, VideoStageConfig)
    _aug_args(s)
    _window_args(s)
    _loop_args(s, steps=2000, lr=5e-5)
    s.set_defaults(func=cmd_video)

    s = sub.add_parser("lcm", help="LCM distillation of the video model for 2-step sampling")
    s.add_argument("--teacher", type=Path, required=True, help="video run (newest checkpoint) or video model folder")
    s.add_argument("--student-init", type=Path, default=None,
                   help="start the student from this LCM run's or model folder's lcm_unet (same architecture) "
                        "instead of from the teacher")
    s.add_argument("--cache", type=Path, required=True)
    s.add_argument("--out", type=Path, required=True)
    _stage_args(s, LCMStageConfig)
    _aug_args(s)
    _window_args(s)
    _loop_args(s, steps=1000, lr=1e-5, ema=0.99)
    s.set_defaults(func=cmd_lcm)

    s = sub.add_parser("encoder", help="distil the VAE encoder, without its attention, for the conditioning channels (faster encoding)",
                       description="Starts from a finished model's VAE encoder built without its mid-block attention and trains it "
                                   "to reproduce the full encoder's latents of albedo, normal, roughness, metallic and the shading "
                                   "prior. The run's model/ is the teacher plus channel_encoder.safetensors; render or evaluate it "
                                   "with --channel-encoder distilled, ship it with `x2video train ship`.")
    s.add_argument("--teacher", type=Path, required=True, help="video (or LCM) run or model folder whose VAE is distilled")
    s.add_argument("--data", type=Path, required=True, help="data set folder with train/ and test/ rooms")
    s.add_argument("--out", type=Path, required=True, help="run folder")
    _stage_args(s, EncoderStageConfig, aliases=_POOL, overrides={
        "size": {**_SIZE["size"], "help": "resize frames to WxH (default: the teacher's training size)"}})
    _loop_args(s, steps=2000, lr=3e-4, ema=0.995)
    s.set_defaults(func=cmd_encoder)

    register_small(sub)

    s = sub.add_parser("ship", help="write a trained model (fp16 safetensors + training.json) into resources/",
                       description="Copies the newest model of a run (lcm, video or image) in fp16 into OUT with a "
                                   "training.json recording the training size and the runs' results, so `x2video render`, "
                                   "the editor and `x2video eval` pick it up.")
    s.add_argument("--model", type=Path, required=True, help="lcm or video run (newest checkpoint) or model folder")
    s.add_argument("--image", type=Path, default=None, help="image run shipped beside it in OUT/image (eval table a)")
    s.add_argument("--out", type=Path, required=True, help="e.g. resources/x2video-tiny")
    s.add_argument("--size", type=size_arg, default=None, help="training size WxH (default: read from the run's latent cache)")
    s.add_argument("--run", type=Path, action="append", default=[], help="training run folder whose summary/results go into training.json (repeatable)")
    s.add_argument("--overwrite", action="store_true", help="replace an existing OUT")
    s.add_argument("--keep-runs", action="store_true",
                   help="with --overwrite: carry the replaced OUT/training.json's run records and shipped sources "
                        "(for a model continued from the shipped one, whose earlier runs' folders may be gone)")
    s.set_defaults(func=cmd_ship)
