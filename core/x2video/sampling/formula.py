"""`formula_frames`: a render with tier 0 alone (`x2video.sampling.tier_formula`), as a function.

Albedo x irradiance of each frame's (edited) channels, zero inside A|M|R regions: exact for diffuse light, no
weights, any frame size. The same render as `Renderer(None).render` with quality 'formula' (the same events), kept
for callers that have no Renderer.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from x2video.sampling.events import CancelToken, EventCallback
from x2video.sampling.renderer import Renderer
from x2video.sampling.settings import RenderSettings
from x2video.sampling.tier_formula import FormulaTier

if TYPE_CHECKING:
    from x2video.edits.model import Edits
    from x2video.shot import Shot


def formula_frames(
    shot: Shot,
    edits: Edits | None,
    settings: RenderSettings,
    on_event: EventCallback | None = None,
    cancel: CancelToken | None = None,
    *,
    base_dir: str | Path | None = None,
) -> None:
    """Render `settings.frames` (default all) of `shot` under `edits` (or None) with the formula, whatever
    `settings.quality` says (`Renderer.render`'s events; prompts and the reference frame do not apply)."""
    Renderer(None).render(shot, edits, dataclasses.replace(settings, quality=FormulaTier.name), on_event, cancel, base_dir=base_dir)
