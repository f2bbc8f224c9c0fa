"""Model checkpoints: a directory of safetensors (fp16 or fp32) plus `config.json` holding the `ModelConfig`.

    DIR/config.json            {"format": "x2video-model", "version": 1, "config": {...ModelConfig...}}
    DIR/unet.safetensors       the (video or image) UNet, Hybrid Self-Attention weights included
    DIR/vae.safetensors        the AutoencoderKL
    DIR/lcm_unet.safetensors   optional: an LCM-distilled UNet of the same config
    DIR/channel_encoder.safetensors  optional: the distilled encoder of the conditioning channels

Loading validates every tensor name and shape and reports all mismatches at once.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file
from torch import nn

from x2video.io.atomic import atomic_path, write_text_atomic
from x2video.model.config import ModelConfig

FORMAT = "x2video-model"
VERSION = 1
PARTS = ("unet", "vae", "lcm_unet", "channel_encoder")


def _cast_state(state: dict[str, torch.Tensor], dtype: torch.dtype, part: str) -> dict[str, torch.Tensor]:
    """CPU copies with floating tensors in `dtype`; a tensor that is not finite after the cast
    (NaN in training, or too large for float16) is an error, not a silently broken file."""
    out = {}
    for k, v in state.items():
        v = v.detach().to("cpu", dtype) if v.is_floating_point() else v.detach().cpu()
        if v.is_floating_point() and not torch.isfinite(v).all():
            raise ValueError(f"{part}: tensor {k} has non-finite values in {str(dtype).replace('torch.', '')}; not writing a broken checkpoint")
        out[k] = v.contiguous()
    return out


def save_checkpoint(directory: str | os.PathLike, config: ModelConfig, modules: dict[str, nn.Module | dict[str, torch.Tensor]],
                    dtype: torch.dtype = torch.float32) -> Path:
    """Write `modules` (names from PARTS; modules or their state dicts) and the config into
    `directory` (created if needed), floating tensors cast to `dtype`."""
    if dtype not in (torch.float16, torch.float32, torch.bfloat16):
        raise ValueError(f"checkpoint dtype must be float16, bfloat16 or float32, got {dtype}")
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    for name, module in modules.items():
        if name not in PARTS:
            raise ValueError(f"unknown checkpoint part {name!r} (expected one of {PARTS})")
        sd = _cast_state(module.state_dict() if isinstance(module, nn.Module) else module, dtype, name)
        with atomic_path(out / f"{name}.safetensors") as tmp:  # a kept file is never half-written
            save_file(sd, str(tmp), metadata={"format": FORMAT})
    write_text_atomic(out / "config.json", json.dumps({"format": FORMAT, "version": VERSION, "config": config.to_dict()}, indent=2, sort_keys=True))
    return out


def read_config(directory: str | os.PathLike) -> ModelConfig:
    """The `ModelConfig` of a checkpoint directory."""
    path = Path(directory) / "config.json"
    if not path.is_file():
        raise FileNotFoundError(f"not an X2Video checkpoint: {path} is missing")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: invalid JSON ({e})") from e
    if data.get("format") != FORMAT:
        raise ValueError(f"{path}: format is {data.get('format')!r}, expected {FORMAT!r}")
    if data.get("version") != VERSION:
        raise ValueError(f"{path}: version {data.get('version')} not supported (this code reads {VERSION})")
    try:
        return ModelConfig.from_dict(data["config"])
    except (TypeError, ValueError, KeyError) as e:
        raise ValueError(f"{path}: bad model config: {e}") from e


def load_into(module: nn.Module, file: str | os.PathLike, part: str) -> None:
    """Load a safetensors file into `module`, raising one ValueError that names every missing,
    unexpected or mis-shaped tensor."""
    file = Path(file)
    if not file.is_file():
        raise FileNotFoundError(f"checkpoint file missing: {file}")
    sd = load_file(str(file))
    own = module.state_dict()
    problems = []
    for k in sorted(set(own) - set(sd)):
        problems.append(f"{part}: missing tensor {k} (model shape {tuple(own[k].shape)})")
    for k in sorted(set(sd) - set(own)):
        problems.append(f"{part}: unexpected tensor {k} (checkpoint shape {tuple(sd[k].shape)})")
    for k in sorted(set(sd) & set(own)):
        if sd[k].shape != own[k].shape:
            problems.append(f"{part}: {k}: checkpoint shape {tuple(sd[k].shape)} != model shape {tuple(own[k].shape)}")
    if problems:
        raise ValueError(f"{file} does not match the model built from its config.json:\n  " + "\n  ".join(problems))
    ref = next(iter(own.values())) if own else None
    dtype = ref.dtype if ref is not None and ref.is_floating_point() else torch.float32
    module.load_state_dict({k: (v.to(dtype) if v.is_floating_point() else v) for k, v in sd.items()}, strict=True)
