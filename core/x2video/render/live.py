"""A live preview of an edit (issue 43): one frame, at once with the fastest tier auto trusts, then at full quality.

While a person drags a slider the frame on screen re-renders with a per-frame tier: tier 1 where the render would
use it (auto's choice, or the regions' base of a regional diffusion render), otherwise the formula
(`preview_choice`, read from `tiers.decide`, so the rules stay there). When they stop, the same frame renders with
the tier the render itself runs (`render_frame` with the settings' own quality): for a per-frame tier that is the
preview's frame; for the diffusion sampler, the window of `RenderSettings.window` frames around it (a whole-shot
render's keyframes sit elsewhere, so its frame may differ). Both go through `Renderer.render`, the one entry point
the command line, the editor and the benchmarks share.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from x2video.render.events import CancelToken, FramesReady, RenderFailed, RenderStarted
from x2video.render.settings import RenderSettings
from x2video.tiers import registry as tiers
from x2video.tiers.base import TierChoice

if TYPE_CHECKING:
    from x2video.edits.model import Edits
    from x2video.model.api import RenderModel
    from x2video.render.renderer import Renderer
    from x2video.shot import Shot


@dataclass(frozen=True)
class LiveChoice:
    """What a live preview of an edit runs: `preview` (a per-frame tier) while the edit changes, `full` (what a render
    at the settings' quality runs; None where it cannot run, `preview.reason` says why) once it settles."""

    preview: TierChoice
    full: TierChoice | None

    @property
    def same(self) -> bool:
        """The preview is already the full-quality frame (a per-frame tier renders both)."""
        return self.full is not None and self.full.tier == self.preview.tier and not self.full.regions


def preview_choice(quality: str, shot: Shot, edits: Edits | None, model: RenderModel | None, base: str = "auto") -> LiveChoice:
    """The tiers of a live preview of `shot` under `edits` at `quality` on `model` (None: not built; the formula);
    `base`: the render's `RenderSettings.base`."""
    try:
        full = tiers.decide(quality, shot, edits, model, base)
    except ValueError as e:  # the render could not run this (no model, no tier-1 net): the formula needs neither
        return LiveChoice(TierChoice(tiers.FORMULA, f"the formula ({e})"), None)
    if tiers.get(full.tier).per_frame:
        return LiveChoice(full, full)
    if full.base and tiers.get(full.base).per_frame:  # a regional render: its base stands in until the sampler's frame
        return LiveChoice(TierChoice(full.base, f"{full.base} stands in for the diffusion sampler ({full.reason})"), full)
    return LiveChoice(TierChoice(tiers.FORMULA, f"the formula stands in for the diffusion sampler ({full.reason})"), full)


def frame_window(t: int, num_frames: int, window: int) -> tuple[int, int]:
    """[start, stop) of `window` frames of a `num_frames` shot around frame `t` (fewer when the shot is shorter)."""
    n = max(1, min(window, num_frames))
    start = min(max(0, t - n // 2), num_frames - n)
    return start, start + n


@dataclass
class LiveFrame:
    """Frame `t` as one live render made it: linear RGB float32 (H, W, 3), by `tier` (and why), in `seconds`."""

    t: int
    image: np.ndarray
    tier: str
    reason: str
    seconds: float
    frames: tuple[int, int]  # the frames the render covered ([t, t + 1) for a per-frame tier)


def render_frame(renderer: Renderer, shot: Shot, edits: Edits | None, settings: RenderSettings, t: int,
                 cancel: CancelToken | None = None) -> LiveFrame | None:
    """Frame `t` of `shot` under `edits`, rendered by `renderer` with `settings` (its quality decides the tier): frame t
    alone for a per-frame tier, the sampler's window around it for the diffusion tier (stopped once t is made).
    None when cancelled before t was made; a failed render raises, as `Renderer.render` does."""
    choice = renderer.choose_tier(shot, edits, settings)
    frames = (t, t + 1) if tiers.get(choice.tier).per_frame else frame_window(t, shot.num_frames, settings.window)
    token = cancel if cancel is not None else CancelToken()
    got: dict[str, object] = {}
    t0 = time.perf_counter()

    def on_event(ev) -> None:
        if isinstance(ev, RenderStarted):
            got["tier"], got["reason"] = ev.tier, ev.reason
        elif isinstance(ev, FramesReady) and t in ev.frames and "image" not in got:
            got["image"] = np.asarray(ev.frames[t], np.float32)
            token.cancel()  # the rest of the window is not shown
        elif isinstance(ev, RenderFailed):
            got["error"] = ev.error

    renderer.render(shot, edits, dataclasses.replace(settings, frames=frames), on_event, token)
    if "image" not in got:
        return None
    return LiveFrame(t, got["image"], str(got.get("tier", choice.tier)), str(got.get("reason", choice.reason)),  # type: ignore[arg-type]
                     time.perf_counter() - t0, frames)


__all__ = ["LiveChoice", "LiveFrame", "frame_window", "preview_choice", "render_frame"]
