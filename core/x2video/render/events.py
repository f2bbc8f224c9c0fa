"""The cancel token and the typed events a `Renderer` emits (CLI, editor and bench share them)."""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Callable, Union

import numpy as np

__all__ = ["CancelToken", "Cancelled", "RenderStarted", "WindowStarted", "StepDone", "FramesReady", "RenderFinished",
           "RenderCancelled", "RenderFailed", "RenderEvent", "EventCallback"]


class CancelToken:
    """Thread-safe flag; the Renderer and samplers check it between denoising steps."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def cancel(self) -> None:
        self._event.set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()


class Cancelled(Exception):
    """Raised inside the sampler when the token is set; the Renderer turns it into a `RenderCancelled` event."""


@dataclass
class RenderStarted:
    num_frames: int
    num_windows: int
    levels: list[int]  # levels in the order they will run (top level = keyframes first)
    tier: str = "diffusion"  # what renders: a tier's name (`x2video.tiers.base.TIERS`)
    reason: str = ""  # why that tier (quality 'auto'), for the log and the status bar
    per_frame: bool = False  # the tier renders every frame on its own (`x2video.tiers.base.PerFrameTier`): progress in frames


@dataclass
class WindowStarted:
    index: int  # window number in plan order
    frames: list[int]  # shot frame indices of the window positions
    mode: str  # "key" | "interp" | "seq"
    level: int


@dataclass
class StepDone:
    window: int
    step: int  # 1-based
    steps: int


@dataclass
class FramesReady:
    """Newly finished frames: linear RGB float32 (H, W, 3) each; `level` they were produced at."""

    window: int
    frames: dict[int, np.ndarray]
    level: int
    mode: str
    seconds: float  # wall time of the window that produced them
    replaces: tuple[int, ...] = ()
    """Frames among `frames` that an earlier event already delivered and these replace (the seam pass)."""
    window_done: bool = True
    """False when more frames of this window follow in another event (the first window delivers its first
    keyframe alone, so an editor can show it while the rest decode)."""


@dataclass
class RenderFinished:
    num_frames: int
    seconds: float


@dataclass
class RenderCancelled:
    frames_done: list[int]


@dataclass
class RenderFailed:
    error: str


RenderEvent = Union[RenderStarted, WindowStarted, StepDone, FramesReady, RenderFinished, RenderCancelled, RenderFailed]
EventCallback = Callable[[RenderEvent], None]
