"""Where the editor's model comes from: shipped weights in resources/ by default, or an explicitly
labelled untrained tiny model (smoke renders only)."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

#: The repository's resources/ folder (the shipped fp16 safetensors live there).
REPO_RESOURCES = Path(__file__).resolve().parents[1] / "resources"

HOW_TO_GET_WEIGHTS = (
    "The shipped model weights were not found in {dir}.\n\n"
    "To get them: pull the repository's resources/ folder (the fp16 safetensors and the model card), "
    "or train them yourself with the `x2video train` command (see resources/MODEL_CARD.md for the exact "
    "commands), or point the X2VIDEO_WEIGHTS environment variable at a checkpoint folder.\n\n"
    "You can still try the editor with an UNTRAINED tiny model: it runs the whole pipeline "
    "(keyframes, interpolation levels, progress, cancel, export) but its frames are noise-like, not renders."
)


def has_weights(d: Path | None) -> bool:
    """A checkpoint folder as `X2VideoModel.save_pretrained` writes it: config.json, unet and vae safetensors."""
    if d is None:
        return False
    d = Path(d)
    return all((d / f).is_file() for f in ("config.json", "unet.safetensors", "vae.safetensors"))


def weights_dir() -> Path:
    """X2VIDEO_WEIGHTS if set; else resources/ or the first folder directly inside it holding a checkpoint."""
    env = os.environ.get("X2VIDEO_WEIGHTS")
    if env:
        return Path(env)
    if has_weights(REPO_RESOURCES):
        return REPO_RESOURCES
    if REPO_RESOURCES.is_dir():
        for sub in sorted(p for p in REPO_RESOURCES.iterdir() if p.is_dir()):
            if has_weights(sub):
                return sub
    return REPO_RESOURCES


def cuda_available() -> bool:
    """Whether torch sees a CUDA device (False where torch cannot tell)."""
    try:
        import torch

        return bool(torch.cuda.is_available())
    except Exception:  # noqa: BLE001 - a broken CUDA install means the CPU
        return False


def resolve_device(choice: str | None) -> str:
    """The torch device for the Render panel's choice: "auto" (or None) = cuda when available, else cpu."""
    if choice in (None, "", "auto"):
        return "cuda" if cuda_available() else "cpu"
    if choice not in ("cpu", "cuda"):
        raise ValueError(f"unknown device {choice!r} (use auto, cpu or cuda)")
    return choice


@dataclass(frozen=True)
class ModelChoice:
    """What to load: 'pretrained' (from `path`) or 'untrained' (the tiny preset, random weights), on `device`."""

    kind: str
    path: Path | None = None
    device: str = "cpu"

    @property
    def label(self) -> str:
        return f"Model: {self.path.name if self.path else '?'}" if self.kind == "pretrained" else "Model: UNTRAINED tiny (smoke test)"

    @property
    def detail(self) -> str:
        if self.kind == "pretrained":
            return f"Trained weights from {self.path}"
        return "Randomly initialised tiny model: it runs the whole pipeline, but its frames are noise, not renders."


def load_model(choice: ModelChoice):
    """Build the model (slow: call it off the GUI thread)."""
    from x2video.model.pipeline import X2VideoModel

    if choice.kind == "pretrained":
        if choice.path is None or not has_weights(choice.path):
            raise FileNotFoundError(HOW_TO_GET_WEIGHTS.format(dir=choice.path))
        return X2VideoModel.from_pretrained(choice.path, device=choice.device)
    if choice.kind == "untrained":
        return X2VideoModel.untrained("tiny", device=choice.device)
    raise ValueError(f"unknown model choice {choice.kind!r}")
