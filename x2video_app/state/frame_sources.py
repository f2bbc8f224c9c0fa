"""Where each frame of the shot comes from, for the timeline's strip and the viewer's badge (Qt-free): the shot's own
path-traced frame (the base, `x2video.base.stage`), a frame filled from its nearest keyframes, or a frame rendered from
the channels; and which tier edited it, as the render's `FramesReady.mode` said (`RenderState.modes`).

Before a render the strip shows the frames that will be the base (a shot with rgb opens showing its path-traced
frames); the keyframes the timeline marks are those of a keyframe shot (rgb on some frames only) or of the
`RenderSettings.keyframes` setting, never every frame of a shot with rgb on each.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from x2video.render.settings import RenderSettings
    from x2video.shot import Shot
    from x2video_app.state.render_state import RenderState

#: a frame's source
PATH_TRACED, FILLED, RENDERED = "path-traced", "filled", "rendered"
#: a frame a generating tier (the diffusion sampler) made: its window modes
GENERATED = "generated"
_WINDOW_MODES = ("key", "interp", "seq")
#: what a frame's strip cell shows, in the legend's order: its edit's tier where one edited it, else its source
KINDS = (PATH_TRACED, FILLED, RENDERED, "formula", "formula+residual", "residual", GENERATED)
_WORDS = {PATH_TRACED: "path-traced", FILLED: "filled from its nearest keyframes", RENDERED: "rendered from the channels",
          "formula": "tier 0's difference (formula)", "formula+residual": "tier 0 and tier 1's differences (formula+residual)",
          "residual": "tier 1 (residual)", GENERATED: "generated (diffusion)"}


def path_traced_frames(shot: Shot | None, settings: RenderSettings) -> tuple[int, ...]:
    """The frames a render of `shot` with `settings` keeps as its own path-traced frames: the shot's rgb frames, or the
    `keyframes` setting's; () when the settings turn the base off, the shot has no rgb, or the setting names no frame
    of it (the render says why)."""
    from x2video.base.keyframes import keyframed
    from x2video.base.plan import uses_base

    if shot is None or not uses_base(shot, settings):
        return ()
    try:
        return tuple(keyframed(shot, settings).keyframes)
    except ValueError:
        return ()


def keyframe_marks(shot: Shot | None, settings: RenderSettings) -> tuple[int, ...]:
    """The keyframes the timeline marks: the path-traced frames of a keyframe shot (rgb with gaps) or of the
    `keyframes` setting; () when every frame is path-traced (nothing between to fill) or there is no base."""
    frames = path_traced_frames(shot, settings)
    return () if shot is None or len(frames) == shot.num_frames else frames


def edit_tier(mode: str) -> str | None:
    """The tier that edited a frame that arrived with `mode` (`FramesReady.mode`); None for the base unchanged."""
    from x2video.base.stage import BASE

    if mode == BASE:
        return None
    return GENERATED if mode in _WINDOW_MODES else mode


@dataclass(frozen=True)
class FrameSources:
    """Per frame of the shot: `kinds[t]` (one of `KINDS`; absent: nothing to show yet), the keyframes to mark."""

    num_frames: int
    keyframes: tuple[int, ...]
    path_traced: frozenset[int]
    base: bool  # the frames rendered (or to render) keep the shot's path-traced frames as their base
    kinds: dict[int, str] = field(default_factory=dict)
    tiers: dict[int, str] = field(default_factory=dict)  # rendered frame -> the tier that edited it

    def source(self, t: int) -> str:
        """Where frame t's pixels come from before any edit."""
        if not self.base:
            return RENDERED
        return PATH_TRACED if t in self.path_traced else FILLED

    def badge(self, t: int, rendered: bool) -> str:
        """A line for the viewer: where frame t comes from and which tier edited it (`rendered`: the render made it)."""
        src = _WORDS[self.source(t)]
        if not rendered:
            return f"{src} (not rendered yet)" if self.base and t in self.path_traced else "not rendered yet"
        tier = self.tiers.get(t)
        if tier is None:
            return src
        if not self.base:
            return f"{_WORDS[RENDERED]} ({tier})"
        return f"{src} + {_WORDS.get(tier, tier)}"


def frame_sources(shot: Shot | None, settings: RenderSettings, render: RenderState) -> FrameSources:
    """What the timeline's strip and the badge show: the render's own record (`RenderState.base`, `.path_traced`,
    `.modes`) for the frames it delivered, and for the others the base that `settings` would keep."""
    if shot is None:
        return FrameSources(0, (), frozenset(), False)
    ran = render.status != "idle" or bool(render.modes)
    if ran:
        base, pt = render.base, frozenset(render.path_traced)
        marks = tuple(sorted(pt)) if base and len(pt) < shot.num_frames else ()
    else:
        pt = frozenset(path_traced_frames(shot, settings))
        base, marks = bool(pt), keyframe_marks(shot, settings)
    src = FrameSources(shot.num_frames, marks, pt, base)
    for t in range(shot.num_frames):
        mode = render.modes.get(t)
        if mode is None:
            if base and t in pt:
                src.kinds[t] = PATH_TRACED  # the shot's own frame, there before any render
            continue
        tier = edit_tier(mode)
        if tier is not None:
            src.tiers[t] = tier
        src.kinds[t] = tier if tier is not None and base else src.source(t)
    return src


__all__ = ["FILLED", "GENERATED", "KINDS", "PATH_TRACED", "RENDERED", "FrameSources", "edit_tier", "frame_sources",
           "keyframe_marks", "path_traced_frames"]
