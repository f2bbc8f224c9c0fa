"""The classical baseline on every row: `x2video.model.shading.classical_shading` of the same (edited) channels, no network.

Tone-mapped albedo x irradiance plus the split-sum GGX term from roughness/metallic/normal,
computed from exactly the channels the model is given (after `apply_edits`): with irradiance
dropped or inside an A|M|R-masked region it has nothing to work with and renders black there.
It ignores prompts and reference frames, so "+ Text" / "+ Ref." rows share their baseline.
"""
from __future__ import annotations

import time

import numpy as np

from x2video.conditioning.edited import apply_edits
from x2video.conditioning.frame import plain_conditioning
from x2video.edits import Edits
from x2video.model.shading import classical_shading
from x2video.shot import Shot

DESCRIPTION = (
    "classical shading of the same (edited) channels: albedo x (1 - metallic) x irradiance + irradiance x "
    "split-sum GGX (Karis 2014) from roughness/metallic/normal (x2video.model.shading); black where albedo or "
    "irradiance is missing or masked out (an all-black video scores TC 0); ignores text and reference"
)


def classical_frames(shot: Shot, edits: Edits | None) -> tuple[list[np.ndarray], float]:
    """(T linear (H, W, 3) frames, seconds taken) of the classical shading of `shot` under `edits`."""
    t0 = time.perf_counter()
    frames = []
    for t in range(shot.num_frames):
        cond = plain_conditioning(shot, t) if edits is None else apply_edits(shot, edits, t)
        frames.append(classical_shading(cond.channels, cond.amr_mask))
    return frames, time.perf_counter() - t0
