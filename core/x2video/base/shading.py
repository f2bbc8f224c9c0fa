"""Irradiance where a keyframe shot lacks it: the base's own shading (DESIGN.md "Keyframes": irradiance becomes optional
on the frames between).

A keyframe shot's light passes (DiffDir + DiffInd, DiffCol, the glossy ones) are path-traced with its rgb, on the
keyframes only. An edit over the base still needs each frame's diffuse light for tier 0's difference
(`base.passes.rebuild`), and the base holds it:

- on a frame between keyframes, the fill's demodulated shading ((rgb - emission) / albedo, carried from the nearest
  keyframes: `base.fill`) is the light the filled frame was modulated with, so an albedo edit there is the fill plus
  (new albedo - old albedo) x that shading, and no diffuse colour or glossy pass enters the difference;
- on a keyframe without the irradiance pass (an rgb/ folder with gaps and no irradiance/), its own demodulated shading;
- on a keyframe with its passes, the passes, untouched: the compositor's rebuild, as on a fully rendered shot.

`ShadedShot` is the shot as a render over its base reads it (irradiance on every frame, in the channel's convention:
the shot's irradiance_scale applied), and `supplies_irradiance` says where it is used: the tier choice then counts
irradiance as present (`x2video.tiers.registry.decide`).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from x2video.channels import SPECS
from x2video.shot import Shot

#: what a tier's reason adds where the base supplies irradiance (`x2video.tiers.registry.decide`)
SUPPLIED_NOTE = "irradiance on the frames without it is the base's shading (the fill's between keyframes)"


def supplies_irradiance(shot: Shot) -> bool:
    """A render over the base of `shot` gives every frame irradiance (`ShadedShot`): `shot` is a keyframe shot (rgb on
    some frames, not all) and some frame lacks irradiance."""
    keys = shot.keyframes
    return 0 < len(keys) < shot.num_frames and not shot.has("irradiance")


class ShadedShot(Shot):
    """`shot` with irradiance on every frame: its own where a frame carries it, else `shading(t)` ((H, W, 3) float32 in
    the irradiance channel's convention, the shot's irradiance_scale applied)."""

    def __init__(self, shot: Shot, shading: Callable[[int], np.ndarray]) -> None:
        self.base_shot, self._shading = shot, shading
        channels = tuple(c for c in SPECS if c in shot.channels or c == "irradiance")
        frames = {c: f for c, f in shot.info.channel_frames.items() if c != "irradiance"}
        self.info = replace(shot.info, channels=channels, channel_frames=frames)

    def _read(self, name: str, t: int) -> np.ndarray:
        if name == "irradiance" and not self.base_shot.has("irradiance", t):
            return self._shading(t)
        return self.base_shot.channel(name, t)

    def __getattr__(self, name: str):
        return getattr(self.base_shot, name)  # a loader's extras (motion, frame_path)
