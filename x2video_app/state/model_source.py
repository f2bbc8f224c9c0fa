"""Where the editor's model comes from: the shipped weights (`x2video.weights`) by default, or an explicitly
labelled untrained tiny model (smoke renders only)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from x2video.weights import ENV, is_checkpoint, shipped_weights, where_weights_are_looked_for

HOW_TO_GET_WEIGHTS = (
    "The shipped model weights were not found ({where}).\n\n"
    "To get them: install the x2video-studio package (it ships them) or use a checkout with its resources/ folder, "
    "train them yourself with the `x2video train` command (docs/TRAINING.md), or point the "
    f"{ENV} environment variable at a checkpoint folder.\n\n"
    "You can still try the editor with an UNTRAINED tiny model: it runs the whole pipeline "
    "(keyframes, interpolation levels, progress, cancel, export) but its frames are noise-like, not renders."
)


def has_weights(d: Path | None) -> bool:
    """A checkpoint folder as `X2VideoModel.save_pretrained` writes it: config.json, unet and vae safetensors."""
    return is_checkpoint(d)


def weights_dir() -> Path | None:
    """The folder the editor loads by default (`x2video.weights.shipped_weights`), or None when there is none."""
    return shipped_weights()


def weights_hint() -> str:
    """HOW_TO_GET_WEIGHTS, saying where the weights were looked for."""
    d = weights_dir()
    return HOW_TO_GET_WEIGHTS.format(where=str(d) if d is not None else where_weights_are_looked_for())


def cuda_possible() -> bool:
    """False where no CUDA device can be there, told without importing torch (seconds at start-up): no torch,
    a CPU-only torch build, or Linux without NVIDIA's driver (or WSL's GPU) device nodes."""
    import sys
    from importlib import metadata

    try:
        version = metadata.version("torch")
    except metadata.PackageNotFoundError:
        return False
    if "+cpu" in version:
        return False
    if sys.platform.startswith("linux"):
        return any(Path(p).exists() for p in ("/proc/driver/nvidia/version", "/dev/nvidiactl", "/dev/dxg"))
    return True


def cuda_available() -> bool:
    """Whether torch sees a CUDA device (False where torch cannot tell); imports torch only where
    `cuda_possible` (the window asks at start-up, on the GUI thread)."""
    import sys

    if "torch" not in sys.modules and not cuda_possible():
        return False
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
    from x2video.weights import load_model as load

    if choice.kind == "pretrained":
        if choice.path is None or not has_weights(choice.path):
            raise FileNotFoundError(HOW_TO_GET_WEIGHTS.format(where=choice.path))
        return load(choice.path, device=choice.device)
    if choice.kind == "untrained":
        return load(untrained=True, device=choice.device)
    raise ValueError(f"unknown model choice {choice.kind!r}")
