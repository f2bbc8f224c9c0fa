"""The base stage of a render: where a shot carries its own path-traced rgb, that is the frame, and tiers render
only what an edit changes (DESIGN.md, "Path-traced pixels first").

- No edit reaches a frame: the frame is the base (the shot's rgb, or on a keyframe shot the fill from its nearest
  keyframes, `base.fill`), and no tier runs.
- An edit reaches it: per pixel, the base plus a tier's difference (`base.difference`): tier 0's (the frame rebuilt
  from its passes, `base.passes`: the compositor's rebuild, exact for albedo edits of diffuse surfaces; a ratio where
  only the light changed, exact for a light edit of every lamp) where only albedo or the light changed, tier 1's where
  roughness, metallic or normal changed (the glossy change no rebuild from passes makes; not where a surface was only
  made glossier, `difference.sharpened`), when the render runs tier 1 (auto with the tier-1 net, or forced); a forced
  formula renders tier 0's everywhere.
- A tier that generates (windows: the diffusion sampler) renders as today; its frame replaces the base inside the
  edit's reach and the base stays everywhere else.

Frames leave in the model's exposure, as every tier's (the base times the shot's irradiance_scale), as float64 so
that the writers' division by the same scale gives the base's float32 values back exactly.
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Callable

import numpy as np

from x2video.base.difference import (
    GLOSSY_CHANNELS,
    LIGHT_MODE,
    MATERIAL_MODE,
    SPILL_MARGIN,
    HowOver,
    changed,
    grow,
    light_only,
    over_base,
    relit_metal,
    sharpened,
)
from x2video.base.fill import FillConfig, fill_frame
from x2video.base.keyframes import only_keyframes
from x2video.base.passes import rebuild
from x2video.render.events import Cancelled, CancelToken, FramesReady, RenderEvent, RenderStarted
from x2video.tiers.base import RenderPlan, TierChoice

if TYPE_CHECKING:
    from x2video.conditioning.frame import FrameConditioning
    from x2video.edits.model import Edits
    from x2video.render.settings import RenderSettings
    from x2video.shot import Shot
    from x2video.tiers.base import Emit, RenderJob, Tier

#: what `RenderStarted.tier` and `FramesReady.mode` say for frames that are the base with no tier's change
BASE = "base"


def base_available(shot: Shot) -> bool:
    """The shot carries path-traced rgb on at least one frame."""
    return bool(shot.keyframes)


def uses_base(shot: Shot, settings: RenderSettings) -> bool:
    """A render of `shot` with `settings` renders over the shot's base (`RenderSettings.base` 'auto', rgb on some frame)."""
    return settings.base == "auto" and base_available(shot)


def changes_nothing(edits: Edits | None) -> bool:
    """`edits` change no pixel of the base: none, or no operation, dropped channel, local prompt or reference (masks
    alone change nothing; a global prompt alone changes nothing a tier would render over the base)."""
    return edits is None or not (edits.ops or edits.dropped or edits.local_prompt_masks() or edits.reference is not None)


def keyframed(shot: Shot, settings: RenderSettings) -> Shot:
    """`shot` with rgb kept on `RenderSettings.keyframes` only (`base.keyframes.only_keyframes`), or as it is when unset."""
    return shot if settings.keyframes is None else only_keyframes(shot, settings.keyframes)


def base_choice(shot: Shot, edits: Edits | None, settings: RenderSettings) -> TierChoice | None:
    """What a render that runs no tier says it runs (every frame is the base: `uses_base` and `changes_nothing`); None
    when a tier must run, which the tiers decide (`x2video.tiers.registry.decide`). Needs no model."""
    if not (uses_base(shot, settings) and changes_nothing(edits)):
        return None
    return TierChoice(BASE, f"no edits: the shot's path-traced frames ({_keys_text(shot)}); base 'off' re-renders them")


def base_plan(shot: Shot, edits: Edits | None, settings: RenderSettings) -> RenderPlan | None:
    """The plan of a render that runs no tier (`base_choice`): per frame, no model; None when a tier must run."""
    choice = base_choice(shot, edits, settings)
    if choice is None:
        return None
    from x2video.render.settings import frame_range

    return RenderPlan(choice.tier, choice.reason, frame_range(shot, settings), per_frame=True)


def render(job: RenderJob, tier: Tier | None, emit: Emit, cancel: CancelToken | None, done: set[int]) -> None:
    """The Renderer's one call: `job` over the shot's base where it has one and the settings use it (`uses_base`), else
    `tier` renders it as it always has. `tier` None: no tier runs (`base_choice`)."""
    if uses_base(job.shot, job.settings):
        render_over_base(job, tier, emit, cancel, done)
        return
    if tier is None:
        raise ValueError(f"no tier to render shot {job.shot.info.source!r}: it has no path-traced frames to be the base")
    tier.render(job, emit, cancel, done)


class BaseFrames:
    """Frame t's base in the model's exposure (float64): the shot's rgb, or the fill between its keyframes."""

    def __init__(self, shot: Shot, cfg: FillConfig = FillConfig()) -> None:
        self.shot, self.cfg = shot, cfg
        self.scale = float(shot.info.irradiance_scale)
        self._shading: dict = {}  # fill_frame's cache across frames (keyframes' shading, the frames in reach)
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
                 residual: Callable[[list[FrameConditioning]], list[np.ndarray]] | None, margin: int = SPILL_MARGIN,
                 mode: HowOver = "auto", sharpen: bool = False) -> tuple[np.ndarray, str]:
    """One frame: `base` (model exposure, float64) with the edit's changes, and which tiers made them.

    Tier 0's R is the frame rebuilt from its passes (`base.passes.rebuild`: the compositor's rebuild where the shot has
    Cycles' passes, albedo x irradiance where it has not), over the base as a ratio where the edit changed only the
    light and as a difference elsewhere (mode "auto": `difference.LIGHT_MODE`, `MATERIAL_MODE`; or one mode
    everywhere). Tier 1's difference replaces it where roughness, metallic or normal changed (`glossy_tier` with a
    `residual`), except where a surface was only made glossier (`difference.sharpened`; `sharpen` takes tier 1's
    there too, for measuring)."""
    everything = changed(original, edited)
    if not everything.any():
        return base, BASE
    reach = grow(everything, margin)
    light = light_only(original, edited) if mode == "auto" else None
    edited = relit_metal(original, edited)
    r_e, r_o = rebuild(edited, original), rebuild(original, original)
    if light is None:
        out = over_base(base, r_e, r_o, reach, mode)  # type: ignore[arg-type]
    else:
        out = over_base(base, r_e, r_o, reach & ~light, MATERIAL_MODE)
        out = np.where(light[..., None], over_base(base, r_e, r_o, light, LIGHT_MODE), out)
    if not (glossy_tier and residual is not None):
        return out, "formula"
    glossy_changed = changed(original, edited, GLOSSY_CHANNELS)
    if not sharpen:
        glossy_changed &= ~sharpened(original, edited)
    glossy = grow(glossy_changed, margin) & reach
    if not glossy.any():
        return out, "formula"
    r_e, r_o = residual([edited, original])
    return np.where(glossy[..., None], over_base(base, r_e, r_o, glossy, MATERIAL_MODE if mode == "auto" else mode), out), "formula+residual"  # type: ignore[arg-type]


def render_over_base(job: RenderJob, tier: Tier | None, emit: Emit, cancel: CancelToken | None, done: set[int]) -> None:
    """Render `job` over the shot's base: every frame the base where no edit reaches it, else base + the tiers'
    differences (per-frame tiers) or the tier's frame inside the edit's reach (a generative tier); emits the events
    every tier emits (RenderStarted, FramesReady) in `base_order`, a few frames per batch, one event per mode in a batch."""
    from x2video.conditioning.edited import frame_conditioning

    shot = job.shot
    bases = BaseFrames(shot)
    original = frame_conditioning(shot, None)
    generative = tier is not None and not tier.per_frame
    glossy = tier is not None and tier.name != "formula" and job.model is not None and getattr(job.model, "residual_net", None) is not None
    residual = _residual_fn(job) if glossy else None
    if generative:
        assert tier is not None
        _generative_over_base(job, tier, bases, original, emit, cancel, done)
        return
    order = base_order(shot, *job.frames)
    reason = job.choice.reason if job.choice.tier == BASE else f"{job.choice.reason}; over the shot's path-traced frames ({_keys_text(shot)})"
    emit(RenderStarted(num_frames=len(order), num_windows=0, levels=[0], tier=job.choice.tier, reason=reason, per_frame=True))
    for index, i in enumerate([0, *range(1, len(order), 4)]):
        if cancel is not None and cancel.cancelled:
            raise Cancelled(f"cancelled after {len(done)} frames")
        tw = time.perf_counter()
        fs = order[i:i + 4] if i else order[:1]
        by_mode: dict[str, dict[int, np.ndarray]] = {}
        for t in fs:
            with job.clock.stage("base"):
                base = bases(t)
            if changes_nothing(job.edits):
                frame, mode = base, BASE
            else:
                frame, mode = edited_frame(base, original(t), job.conditioning(t), glossy_tier=glossy, residual=residual)
            by_mode.setdefault(mode, {})[t] = frame
        done.update(fs)
        seconds = time.perf_counter() - tw
        for k, (mode, frames) in enumerate(by_mode.items()):  # one event per mode: `FramesReady.mode` holds for each of its frames
            emit(FramesReady(window=index, frames=frames, level=0, mode=mode, seconds=seconds,
                             window_done=k == len(by_mode) - 1))


def base_order(shot: Shot, start: int, stop: int) -> list[int]:
    """Frames of [start, stop) in the order a render over the base makes them: coarse to fine (`tiers.base.coarse_to_fine`)
    where every frame carries rgb; on a keyframe shot its keyframes first, then the frames between nearest a keyframe
    first (the best filled, as the fill's quality falls with the distance), coarse to fine among equals."""
    from x2video.tiers.base import coarse_to_fine

    order = coarse_to_fine(start, stop)
    keys = np.asarray(shot.keyframes, np.int64)
    if len(keys) == 0 or len(keys) == shot.num_frames:
        return order
    rank = {t: i for i, t in enumerate(order)}
    ts = np.asarray(order, np.int64)
    i = np.clip(np.searchsorted(keys, ts), 1, len(keys) - 1) if len(keys) > 1 else np.zeros_like(ts)
    dist = np.minimum(np.abs(keys[i] - ts), np.abs(keys[np.maximum(i - 1, 0)] - ts))
    return sorted(order, key=lambda t: (int(dist[rank[t]]), rank[t]))


def _residual_fn(job: RenderJob) -> Callable[[list[FrameConditioning]], list[np.ndarray]]:
    from x2video.tiers.residual import residual_frames

    def run(conds: list[FrameConditioning]) -> list[np.ndarray]:
        assert job.model is not None
        with job.clock.stage("residual"):
            return residual_frames(job.model.residual_net, conds, job.model.device, 4, job.settings.guess_unseen, job.settings.residual_pixels)

    return run


def _generative_over_base(job: RenderJob, tier: Tier, bases: BaseFrames, original: Callable[[int], FrameConditioning], emit: Emit,
                          cancel: CancelToken | None, done: set[int]) -> None:
    """A tier that generates renders its frames as it would; each leaves as the base with the tier's frame inside the
    edit's reach (feathered over the spill margin), the base bit for bit everywhere else."""
    from x2video.base.difference import feathered_reach

    def over(event: RenderEvent) -> None:
        if isinstance(event, FramesReady):
            out = {}
            for t, f in event.frames.items():
                base = bases(t)
                w = feathered_reach(original(t), job.conditioning(t)) if job.edits is not None else None
                out[t] = base if w is None else np.where(w[..., None] > 0, w[..., None] * f + (1 - w[..., None]) * base, base)
            event = FramesReady(window=event.window, frames=out, level=event.level, mode=event.mode, seconds=event.seconds,
                                replaces=event.replaces, window_done=event.window_done)
        emit(event)

    tier.render(job, over, cancel, done)


def base_caption(shot: Shot, settings: RenderSettings) -> str:
    """What a render of `shot` with `settings` keeps as its base, in a line for the editor ('' without rgb)."""
    if not base_available(shot):
        return ""
    if settings.base == "off":
        return "Base off: every frame re-rendered from the channels (the shot's path-traced frames unused)"
    return f"Base: the shot's path-traced frames ({_keys_text(keyframed(shot, settings))})"


def _keys_text(shot: Shot) -> str:
    keys = shot.keyframes
    if len(keys) == shot.num_frames:
        return "rgb on every frame"
    return f"{len(keys)} keyframes of {shot.num_frames} frames, the rest filled"
