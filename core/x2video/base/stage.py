"""The base stage of a render: where a shot carries its own path-traced rgb, that is the frame, and tiers render
only what an edit changes (DESIGN.md, "Path-traced pixels first").

- No edit reaches a frame: the frame is the base (the shot's rgb, or on a keyframe shot the fill from its nearest
  keyframes, `base.fill`), and no tier runs.
- An edit reaches it: per pixel, the base plus a tier's difference (`base.difference`): tier 0's (the formula,
  exact for albedo and light edits of diffuse surfaces, the compositor's rebuild) where only albedo or irradiance
  changed, tier 1's where roughness, metallic or normal changed (the glossy change no rebuild from passes makes), when
  the render runs tier 1 (auto with the tier-1 net, or forced); a forced formula renders tier 0's everywhere.
- A tier that generates (windows: the diffusion sampler) renders as today; its frame replaces the base inside the
  edit's reach and the base stays everywhere else.

Frames leave in the model's exposure, as every tier's (the base times the shot's irradiance_scale), as float64 so
that the writers' division by the same scale gives the base's float32 values back exactly.
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Callable

import numpy as np

from x2video.base.difference import GLOSSY_CHANNELS, SPILL_MARGIN, changed, grow, over_base, relit_metal
from x2video.base.fill import FillConfig, fill_frame

if TYPE_CHECKING:
    from x2video.conditioning import FrameConditioning
    from x2video.shot import Shot

#: what `RenderStarted.tier` and `FramesReady.mode` say for frames that are the base with no tier's change
BASE = "base"


def base_available(shot: Shot) -> bool:
    """The shot carries path-traced rgb on at least one frame."""
    return bool(shot.keyframes)


class BaseFrames:
    """Frame t's base in the model's exposure (float64): the shot's rgb, or the fill between its keyframes."""

    def __init__(self, shot: Shot, cfg: FillConfig = FillConfig()) -> None:
        self.shot, self.cfg = shot, cfg
        self.scale = float(shot.info.irradiance_scale)
        self._shading: dict[int, np.ndarray] = {}
        #: frame -> fraction of its pixels that no keyframe saw (filled frames only)
        self.holes: dict[int, float] = {}

    def input_units(self, t: int) -> np.ndarray:
        """(H, W, 3) float32 base of frame t in the shot's rgb units."""
        if self.shot.has_rgb(t):
            return self.shot.channel("rgb", t)
        res = fill_frame(self.shot, t, self.cfg, shading=self._shading)
        self.holes[t] = res.holes
        return res.rgb

    def __call__(self, t: int) -> np.ndarray:
        return self.input_units(t).astype(np.float64) * self.scale


def edited_frame(base: np.ndarray, original: FrameConditioning, edited: FrameConditioning, *, glossy_tier: bool,
                 residual: Callable[[list[FrameConditioning]], list[np.ndarray]] | None, margin: int = SPILL_MARGIN) -> tuple[np.ndarray, str]:
    """One frame: `base` (model exposure, float64) with the edit's differences, and which tiers made them."""
    from x2video.model.residual import formula

    everything = changed(original, edited)
    if not everything.any():
        return base, BASE
    reach = grow(everything, margin)
    edited = relit_metal(original, edited)
    size = edited.size
    out = over_base(base, formula(edited.channels, size), formula(original.channels, size), reach)
    if not (glossy_tier and residual is not None):
        return out, "formula"
    glossy = grow(changed(original, edited, GLOSSY_CHANNELS), margin) & reach
    if not glossy.any():
        return out, "formula"
    r_e, r_o = residual([edited, original])
    return np.where(glossy[..., None], over_base(base, r_e, r_o, glossy), out), "formula+residual"


def timed(fn: Callable[[], np.ndarray]) -> tuple[np.ndarray, float]:
    t0 = time.perf_counter()
    return fn(), time.perf_counter() - t0
