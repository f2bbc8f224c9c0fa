"""Render settings, cancel token and the typed events a `Renderer` emits (CLI, editor and bench share them)."""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable, Literal, Union

import numpy as np


@dataclass
class RenderSettings:
    """How to sample a shot. Field docstrings double as CLI help."""

    sampler: Literal["ddim", "lcm"] = "ddim"
    """DDIM (v-prediction, trailing spacing) or LCM multistep (needs distilled weights)."""
    steps: int = 20
    """Denoising steps per window (paper: DDIM-20; LCM-2 after distillation)."""
    seed: int = 0
    """Seed of the initial noise; same inputs and seed give identical frames."""
    window: int = 5
    """Frames per window N (the paper trains with N=5)."""
    scheme: Literal["recursive", "sequential"] = "recursive"
    """Recursive Sampling (keyframes, then interpolation levels) or the sequential baseline."""
    frames: tuple[int, int] | None = None
    """Optional [start, stop) range of the shot to render."""
    detail: bool = True
    """Residual models only: add back the classical shading's fine detail that the VAE loses."""
    replace_refs: bool = True
    """Between denoising steps, hold each window's reference frames (those earlier windows
    produced) at their latent noised to the step's level, as in training, instead of letting the
    window re-estimate them (`x2video.sampling.samplers.Known`). On by default (the editor, the
    CLI and the model card's evaluations); False (`--no-replace-refs`) is the ablation."""
    seams: bool = True
    """The seam pass, for the recursive scheme with three levels or more (18 frames or more at
    N = 5): after the first interpolation level, make each keyframe again with its neighbours in a
    window of that level (`x2video.sampling.planner.seam_windows`), so the finer levels
    interpolate between frames that agree. One more window per keyframe; the frames it makes
    again arrive twice (`FramesReady.replaces`). On by default since the model card's "Mean
    anchoring" (with `ref_dc` it raised PSNR and lowered TC on the validation rooms; on `ship_h`
    alone it had cost PSNR with a reference frame, Evaluations 7-8); False (`--no-seams`) is off."""
    max_levels: int | None = None
    """Recursive scheme only: at most this many levels K. None (default): the fewest that let one
    keyframe window span the shot (65 frames at N = 5: K = 3, keyframes 16 apart, the paper's
    example). Fewer levels put the keyframes (N-1)^(K-1) apart and chain the keyframe windows
    (`x2video.sampling.planner.plan_recursive`); K = 1 is sequential sampling in keyframe mode."""
    noise: Literal["window", "frame"] = "frame"
    """How the noise is seeded. 'frame' (default): per frame of the shot, so a frame has the same
    noise in every window that holds it, a reference is re-noised with the noise it was made from,
    and re-rendering a sub-range gives the same noise (`frame_noise`). 'window': each window draws
    its own noise for all its positions (the renders of the model card's Evaluations 1-14)."""
    noise_shared: float = 0.95
    """'frame' noise only: the fraction of the noise's variance every frame of the shot shares, in
    [0, 1] (a mixed noise prior, Ge et al. 2023, "Preserve Your Own Correlation", used here without
    training for it); each frame's noise stays standard normal. Default 0.95: on the held-out shots
    it cut TC by a quarter with all channels, at a PSNR within seed-to-seed chance, and by 40-60 %
    where a channel is missing or masked, at 0.8-1.4 dB of PSNR there (3 seeds, bench/noise_prior.py;
    model card, "Noise shared across frames"); 0 gives independent per-frame noise."""
    ref_dc: float = 1.0
    """Interpolation windows (both ends given), where a frame's lighting must be inferred (the whole
    frame without albedo or irradiance, as there is no classical shading to anchor it; else inside
    its A|M|R mask): at every denoising step pull that region's latent mean per channel (its colour
    and brightness) this fraction of the way to the linear interpolation, by window position, of the
    two references' means over their own regions (statistics matching to the keyframes, as AdaIN on
    latents in Rerender-A-Video, Yang et al. 2023). Where each level
    infers the lighting on its own, the windows disagree on it and every seam of an interpolation
    window shows a brightness jump (`bench/recursive_seams.py`). Default 1 (model card, "Mean
    anchoring"); 0: off. Frames with their shading are left alone: there it cost 0.3 dB on the
    validation rooms for a little TC."""
    resample: int = 1
    """DDIM only: RePaint's resampling (Lugmayr et al. 2022) in windows that hold references: each
    denoising step but the first and last is taken this many times, going back one step's worth of
    noise in between, so the generated frames are denoised again against the references pasted in
    at that level (`x2video.sampling.samplers.sample_ddim`). 1 (default): off; r costs those
    windows about r times the network passes."""
    quality: Literal["formula", "diffusion"] = "diffusion"
    """'diffusion' (default): the diffusion sampler. 'formula': no network, the classical shading
    of the (edited) channels, albedo x irradiance (+ split-sum GGX where roughness and normals are
    given), frame by frame (`x2video.sampling.formula.formula_frames`)."""
    exposure: float | str = "auto"
    """MP4 exposure in stops on the input's radiometric units, or 'auto' (default): the shot's own
    irradiance normalisation, i.e. what the model saw (`x2video.io.units.OutputUnits`). EXR output
    is always in the input's units."""
    preset: Literal["fast", "quality"] | None = None
    """Overrides sampler and steps when set: 'fast' = LCM-2 if distilled weights are loaded, else
    DDIM-4; 'quality' = DDIM-20 (`x2video.sampling.renderer.select_steps`)."""


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
