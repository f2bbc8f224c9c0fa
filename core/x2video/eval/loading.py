"""Loading what an evaluation compares: the video, image and LCM models, and the size to evaluate at.

`x2video eval`, the benches and tests share these; the CLI only turns flags into their arguments.
"""
from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

from x2video.eval.runner import EvalModels
from x2video.io.paths import portable_path
from x2video.weights import ModelOptions

log = logging.getLogger(__name__)


def _step(path: Path) -> int | None:
    m = re.search(r"step-0*(\d+)", str(path))
    return int(m.group(1)) if m else None


def load_eval_models(weights: Path | None, image_weights: Path | None = None, lcm_weights: Path | None = None, *,
                     options: ModelOptions | None = None, with_image: bool = True) -> tuple[EvalModels, Path | None]:
    """(EvalModels, video model folder or None): the video model from `weights` (a training run, its newest
    step-*/model, or a model folder; default the shipped weights), the image model of table (a) and the LCM
    model of table (d) when given; `options` as `x2video.load_model` takes them (`options.weights` is not
    used). Missing or broken weights fail with a clear message. `with_image=False` skips the image model
    (`options.untrained` builds one otherwise)."""
    import torch

    from x2video.model.pipeline import X2VideoModel
    from x2video.train.runs import model_dir
    from x2video.weights import shipped_weights

    o = options or ModelOptions()
    dev = o.device or ("cuda" if torch.cuda.is_available() else "cpu")
    dtype = torch.float16 if o.fp16 else torch.float32
    encoder_dtype = torch.bfloat16 if o.bf16_encoder else None
    channel_encoder = o.channel_encoder
    if o.untrained:
        if weights or image_weights or lcm_weights:
            raise ValueError("--untrained excludes --weights, --image-weights and --lcm-weights")
        video = X2VideoModel.untrained("tiny", device=dev, dtype=dtype)
        image = X2VideoModel.untrained("tiny", seed=1, device=dev, dtype=dtype, video=False) if with_image else None
        info = {r: {"path": "untrained", "untrained": True, "config": "tiny", "video": r == "video"} for r in ("video", "image")}
        return EvalModels(video, image, None, info), None

    if weights is None:
        weights = shipped_weights()
        if weights is None:
            raise FileNotFoundError("no --weights given and no shipped weights found (a folder with config.json and "
                                    "unet.safetensors); pass --weights RUN_OR_DIR, or --untrained for a smoke test")

    def load(path: Path, role: str, want_video: bool, want_lcm: bool = False) -> tuple[Any, dict, Path]:
        if not path.exists():
            raise FileNotFoundError(f"--{role}: {path} does not exist")
        d = model_dir(path)
        for part in ("unet.safetensors", "vae.safetensors"):
            if not (d / part).is_file():
                raise FileNotFoundError(f"--{role}: {d} has no {part}")
        # The image model of table (a) is compared with the video model as the paper's baseline: it encodes its channels
        # like the video model where it can ("distilled" needs its own channel_encoder.safetensors, so "auto" for it).
        enc = "auto" if role == "image-weights" and channel_encoder == "distilled" else channel_encoder
        model = X2VideoModel.from_pretrained(d, device=dev, dtype=dtype, encoder_dtype=encoder_dtype, channel_encoder=enc)
        if model.config.video != want_video:
            kind = "video" if model.config.video else "image"
            raise ValueError(f"--{role}: {d} holds an {kind} model; expected {'a video' if want_video else 'an image'} model")
        if want_lcm and not model.has_lcm:
            raise ValueError(f"--{role}: {d} has no lcm_unet.safetensors (distil one with `x2video train lcm`)")
        info = {"path": portable_path(d), "config": model.config.name, "video": model.config.video, "shading_prior": model.config.shading_prior,
                "lcm": model.has_lcm, "step": _step(d), "untrained": False}
        if encoder_dtype is not None:
            info["encoder_dtype"] = str(encoder_dtype).removeprefix("torch.")
        info["channel_encoder"] = "vae" if model.channel_encoder is None else "distilled"
        return model, info, d

    video, vinfo, vdir = load(Path(weights), "weights", True)
    info = {"video": vinfo}
    image = lcm = None
    if image_weights is not None and with_image:
        image, info["image"], _ = load(Path(image_weights), "image-weights", False)
    if lcm_weights is not None:
        lcm, info["lcm"], _ = load(Path(lcm_weights), "lcm-weights", True, want_lcm=True)
        if info["lcm"]["channel_encoder"] != vinfo["channel_encoder"]:  # table (d) compares samplers, not encoders
            raise ValueError(f"--channel-encoder {channel_encoder}: --weights encodes the channels with its "
                             f"{vinfo['channel_encoder']} encoder, --lcm-weights with its {info['lcm']['channel_encoder']} one; "
                             "pick vae or distilled explicitly")
    elif video.has_lcm:
        info["lcm"] = dict(vinfo, note="lcm_unet.safetensors of --weights")
    return EvalModels(video, image, lcm, info), vdir


def resolve_size(data: Path, split: str, size: tuple[int, int] | None, weights_dir: Path | None,
                 downsample: int) -> tuple[tuple[int, int], str]:
    """(W, H) to evaluate the `split` of the data set `data` at (`size` if given, else the model's training size
    when smaller than the data's, else the data's) and a sentence saying why."""
    from x2video.eval.data import native_size, training_size

    native = native_size(data, split)
    if size is not None:
        size, why = tuple(size), f"--size {size[0]}x{size[1]}"
    else:
        trained = training_size(weights_dir) if weights_dir is not None else None
        if trained is not None and trained[0] * trained[1] < native[0] * native[1]:
            size, why = trained, f"the model was trained at {trained[0]}x{trained[1]}"
        elif trained is not None:
            size, why = native, f"the data's size (model trained at {trained[0]}x{trained[1]})"
        else:
            size, why = native, "the data's size (the weights do not record a training size)"
    if size[0] % downsample or size[1] % downsample:
        raise ValueError(f"evaluation size {size[0]}x{size[1]} ({why}) is not a multiple of the model's VAE factor {downsample}; pass --size")
    if tuple(size) != tuple(native):
        why += f"; ground truth, channels and motion area-downsampled from {native[0]}x{native[1]}"
        if abs(size[0] / size[1] - native[0] / native[1]) > 0.02:
            why += f" (aspect ratio {native[0] / native[1]:.3f} -> {size[0] / size[1]:.3f}: images are stretched)"
            log.warning("evaluation size %dx%d stretches the data's %dx%d frames", size[0], size[1], native[0], native[1])
    return tuple(size), why  # type: ignore[return-value]
