"""The shipped weights, and a model loaded from them or from any checkpoint folder.

Where the shipped weights are, first found wins:
1. the folder the environment variable X2VIDEO_WEIGHTS names;
2. package data: `x2video/resources/x2video-tiny/` inside an installed wheel (in a development
   checkout that path is a link to the repository's resources/);
3. the repository's resources/ folder (a development checkout without the link).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from x2video.model.config import DEFAULT_CHANNEL_ENCODER

if TYPE_CHECKING:
    from x2video.model.pipeline import X2VideoModel

#: environment variable naming a checkpoint folder to use instead of the shipped weights
ENV = "X2VIDEO_WEIGHTS"
#: the shipped model's folder name, under the package's (or the repository's) resources/
NAME = "x2video-tiny"
#: the files every checkpoint folder holds (`x2video.model.checkpoint`)
REQUIRED = ("config.json", "unet.safetensors", "vae.safetensors")

HOW_TO_GET_WEIGHTS = (
    "no trained weights found ({where}). Install the x2video-studio package (it ships them), use a checkout "
    "with its resources/ folder, point the X2VIDEO_WEIGHTS environment variable at a checkpoint folder, or "
    "train them with `x2video train ...` (docs/TRAINING.md)"
)


def is_checkpoint(folder: str | os.PathLike | None) -> bool:
    """Whether `folder` holds a model checkpoint as `X2VideoModel.save_pretrained` writes it."""
    return folder is not None and all((Path(folder) / f).is_file() for f in REQUIRED)


def _candidates() -> list[Path]:
    packaged = resources.files("x2video") / "resources" / NAME
    repo = Path(__file__).resolve().parents[2] / "resources" / NAME
    return [Path(str(packaged)), repo]


def shipped_weights() -> Path | None:
    """The folder of the weights to load by default (see the module docstring), or None when there are none.
    X2VIDEO_WEIGHTS is returned as given, so that a wrong value fails loudly where it is loaded."""
    env = os.environ.get(ENV)
    if env:
        return Path(env)
    return next((p for p in _candidates() if is_checkpoint(p)), None)


def where_weights_are_looked_for() -> str:
    return f"${ENV} unset; looked in " + " and ".join(str(p) for p in _candidates())


@dataclass
class ModelOptions:
    """Which model to load and how (`load_model`'s arguments; the flags of `x2video render`, `x2video eval` and the benches)."""

    weights: Path | None = None
    """model checkpoint folder (unset: $X2VIDEO_WEIGHTS, else the shipped weights)"""
    untrained: bool = False
    """untrained tiny weights instead (a smoke test: the output is noise, not a render)"""
    device: str | None = None
    """torch device (unset: cuda when available, else cpu)"""
    fp16: bool = False
    """half precision (GPU)"""
    bf16_encoder: bool = False
    """run the VAE encoder (the channel encoding, a per-frame cost every sampler pays) in bfloat16 and the rest in
    float32: faster on CPUs with native bf16 (AVX512-BF16, AMX), slower on others"""
    channel_encoder: Literal["vae", "distilled", "auto"] = DEFAULT_CHANNEL_ENCODER  # type: ignore[assignment]
    """what encodes the conditioning channels: 'vae' (the VAE's encoder, what the UNet was trained on), 'distilled'
    (the model folder's channel_encoder.safetensors: the encoder without its mid-block attention, trained to
    reproduce the full encoder's latents) or 'auto' (distilled when the folder has one)"""


def load_model(weights: str | os.PathLike | None = None, *, device: str | None = None, fp16: bool = False,
               bf16_encoder: bool = False, channel_encoder: str = DEFAULT_CHANNEL_ENCODER,
               untrained: bool = False) -> X2VideoModel:
    """A frozen model ready for `Renderer`: from the checkpoint folder `weights`, else the shipped weights.
    The keywords are `ModelOptions`' fields (`load_model(**dataclasses.asdict(options))`)."""
    import torch

    from x2video.model.pipeline import X2VideoModel

    dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
    dtype = torch.float16 if fp16 else torch.float32
    if untrained:
        if weights is not None:
            raise ValueError("untrained weights and a weights folder exclude each other")
        return X2VideoModel.untrained("tiny", device=dev, dtype=dtype)  # test weights: bf16_encoder does not apply
    folder = Path(weights) if weights is not None else shipped_weights()
    if folder is None:
        raise FileNotFoundError(HOW_TO_GET_WEIGHTS.format(where=where_weights_are_looked_for()))
    if not (folder / "config.json").is_file():
        raise FileNotFoundError(f"{folder} is not a model checkpoint folder (no config.json)")
    return X2VideoModel.from_pretrained(folder, device=dev, dtype=dtype, encoder_dtype=torch.bfloat16 if bf16_encoder else None,
                                        channel_encoder=channel_encoder)
