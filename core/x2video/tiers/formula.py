"""Tier 0, the formula: albedo x irradiance of each frame's (edited) channels, zero inside A|M|R regions.

Exact for diffuse light, free: no network, no weights, any frame size (`Renderer(None)` renders it). The
editor's instant preview (`x2video_app.preview`) shows the same frames before a render's own arrive.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from x2video.conditioning.frame import FrameConditioning
from x2video.formula import formula, formula_frame
from x2video.tiers.base import PerFrameTier, RenderJob


class FormulaTier(PerFrameTier):
    """Tier 0: `formula_frame` of every frame."""

    name = "formula"
    needs_model = False
    channels = ("albedo", "irradiance")
    exact_in_part = True

    def frames(self, job: RenderJob, conds: Sequence[FrameConditioning]) -> list[np.ndarray]:
        return [np.asarray(formula_frame(c), np.float32) for c in conds]

    def base_frames(self, job: RenderJob, conds: Sequence[FrameConditioning]) -> list[np.ndarray]:
        """Under a regional render the plain product, not zeroed inside A|M|R regions (the sampler's pixels cover them)."""
        with job.clock.stage("residual"):
            return [formula(c.channels, np.shape(c.amr_mask)[:2] if np.size(c.amr_mask) else None) for c in conds]
