"""The base stage of a render: where a shot carries its own path-traced rgb, that is the frame, and tiers render
only what an edit changes (DESIGN.md, "Path-traced pixels first").

- No edit reaches a frame: the frame is the base (the shot's rgb, or on a keyframe shot the fill from its nearest
  keyframes, `base.fill`), and no tier runs.
- An edit reaches it: per pixel, the base plus a tier's difference (`base.difference.edited_frame`, one call per
  frame): tier 0's (the frame rebuilt
  from its passes, `base.passes`: the compositor's rebuild, exact for albedo edits of diffuse surfaces; on a keyframe
  shot's frames without the light passes, from the base's own shading, `base.shading`; a ratio where
  only the light changed, exact for a light edit of every lamp) where only albedo or the light changed, tier 1's where
  roughness, metallic or normal changed (the glossy change no rebuild from passes makes; not where a surface was only
  made glossier, `difference.sharpened`), when the render runs tier 1 (auto with the tier-1 net, or forced); a forced
  formula renders tier 0's everywhere.
- A tier that generates (windows: the diffusion sampler) renders as today; its frame goes over the base inside the
  edit's reach as a difference over tier 1's frame of the unedited channels (`GeneratedOver`: on the validation room's
  cabinet with its A|M|R masked out and a local prompt, 19.4 dB inside against 18.6 for replacing the base with the
  frame, whole frame 28.7 against 28.1, no seam above doing nothing's in either), the base everywhere else
  (`base.difference.generated_frame`).

What runs is settled before, once (`x2video.base.plan.Plan`: whether the frames go over the base, the tier, the
order, the conditioning); `render` takes that plan.

Frames leave in the model's exposure, as every tier's (the base times the shot's irradiance_scale), as float64 so
that the writers' division by the same scale gives the base's float32 values back exactly.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from x2video.base.difference import BASE, edited_frame, generated_frame
from x2video.base.fill import BaseFrames
from x2video.render.events import Cancelled, CancelToken, FramesReady, RenderEvent, RenderStarted
from x2video.tiers.base import PerFrameTier

if TYPE_CHECKING:
    from x2video.conditioning.frame import Conditioning
    from x2video.tiers.base import Emit, RenderJob, Tier


#: how a generating tier's frame G goes over the base B inside the edit's reach, w its feathered weight
#: (`difference.feathered_reach`): "replace", w G + (1 - w) B; "difference", B + w (G - R), R tier 1's frame of the
#: unedited channels (the tier under a regional render, `TierChoice.base`; else tier 1 where the model has its net,
#: else the formula), so the light the channels do not hold stays the base's as it does for per-frame tiers
GeneratedOver = Literal["replace", "difference"]
GENERATED: tuple[GeneratedOver, ...] = ("replace", "difference")


@dataclass(frozen=True)
class Plan:
    """One render, decided before any frame is made (`x2video.base.plan.make_plan`): `job` is what the tier reads
    (`RenderJob`), `tier` the tier that runs (None: no tier, every frame is the base). Over the base (`over_base`), the
    frames are made in `order`, each the base frame `bases(t)`, or with an edit against its unedited conditioning
    `original`, and `RenderStarted` says `reason`."""

    job: RenderJob
    tier: Tier | None
    over_base: bool
    order: list[int]
    bases: BaseFrames | None
    original: Conditioning | None
    reason: str


def render(plan: Plan, emit: Emit, cancel: CancelToken | None, done: set[int], *, generated: GeneratedOver = "difference") -> None:
    """The Renderer's one call: the plan's job over the shot's base where it has one and the settings use it
    (`Plan.over_base`; a generating tier's frame goes over it as `generated` says), else the plan's tier renders it as
    it always has. `Plan.tier` None: no tier runs (`x2video.base.plan.base_choice`)."""
    if plan.over_base:
        render_over_base(plan, emit, cancel, done, generated=generated)
        return
    if plan.tier is None:
        raise ValueError(f"no tier to render shot {plan.job.shot.info.source!r}: it has no path-traced frames to be the base")
    plan.tier.render(plan.job, emit, cancel, done)


def render_over_base(plan: Plan, emit: Emit, cancel: CancelToken | None, done: set[int], *,
                     generated: GeneratedOver = "difference") -> None:
    """Render the plan's job over the shot's base: every frame the base where no edit reaches it, else base + the tiers'
    differences (per-frame tiers) or the tier's frame inside the edit's reach (a generative tier, as `generated` says:
    `GeneratedOver`); emits the events every tier emits (RenderStarted, FramesReady) in `Plan.order`, a few frames per
    batch, one event per mode in a batch."""
    job, tier, bases, original, order = plan.job, plan.tier, plan.bases, plan.original, plan.order
    assert bases is not None and original is not None
    if tier is not None and not tier.per_frame:
        _generative_over_base(job, tier, bases, original, emit, cancel, done, generated)
        return
    residual = functools.partial(tier.glossy_frames, job) if isinstance(tier, PerFrameTier) and tier.glossy else None
    learned = residual is not None and tier.learned_difference(job)
    emit(RenderStarted(num_frames=len(order), num_windows=0, levels=[0], tier=job.choice.tier, reason=plan.reason, per_frame=True))
    for index, i in enumerate([0, *range(1, len(order), 4)]):
        if cancel is not None and cancel.cancelled:
            raise Cancelled(f"cancelled after {len(done)} frames")
        tw = time.perf_counter()
        fs = order[i:i + 4] if i else order[:1]
        by_mode: dict[str, dict[int, np.ndarray]] = {}
        for t in fs:
            with job.clock.stage("base"):
                base = bases(t)
            if tier is None:  # no edit changes a pixel (`x2video.base.plan.base_choice`)
                frame, mode = base, BASE
            else:
                frame, mode = edited_frame(base, original(t), job.conditioning(t), glossy_tier=residual is not None, residual=residual,
                                           learned=learned)
            by_mode.setdefault(mode, {})[t] = frame
        done.update(fs)
        seconds = time.perf_counter() - tw
        for k, (mode, frames) in enumerate(by_mode.items()):  # one event per mode: `FramesReady.mode` holds for each of its frames
            emit(FramesReady(window=index, frames=frames, level=0, mode=mode, seconds=seconds,
                             window_done=k == len(by_mode) - 1))


def _generative_over_base(job: RenderJob, tier: Tier, bases: BaseFrames, original: Conditioning, emit: Emit,
                          cancel: CancelToken | None, done: set[int], generated: GeneratedOver = "difference") -> None:
    """A tier that generates renders its frames as it would; each leaves as the base with the tier's frame inside the
    edit's reach (feathered over the spill margin), replacing it or as a difference (`GeneratedOver`), the base bit for
    bit everywhere else."""
    if generated not in GENERATED:
        raise ValueError(f"generated: {generated!r} (one of {', '.join(GENERATED)})")
    under = _under_tier(job) if generated == "difference" else None
    unedited: dict[int, np.ndarray] = {}  # frame -> R, tier 1's frame of its unedited channels (a frame may come again, refined)

    def r_unedited(t: int) -> np.ndarray:  # computed once per frame
        if t not in unedited:
            unedited[t] = under.base_frames(job, [original(t)])[0]  # type: ignore[union-attr]
        return unedited[t]

    def over(event: RenderEvent) -> None:
        if isinstance(event, FramesReady):
            out = {}
            for t, f in event.frames.items():
                base = bases(t)
                if job.edits is None:
                    out[t] = base
                    continue
                out[t] = generated_frame(base, f, original(t), job.conditioning(t),
                                         None if under is None else functools.partial(r_unedited, t))
            event = FramesReady(window=event.window, frames=out, level=event.level, mode=event.mode, seconds=event.seconds,
                                replaces=event.replaces, window_done=event.window_done)
        emit(event)

    tier.render(job, over, cancel, done)


def _under_tier(job: RenderJob) -> PerFrameTier:
    """The per-frame tier whose frame of the unedited channels a generated frame is a difference over: the one a regional
    render lays under the sampler's (`TierChoice.base`), else tier 1 where the model has its net, else the formula."""
    from x2video.tiers import registry

    name = job.choice.base or (registry.RESIDUAL if registry.get(registry.RESIDUAL).available(job.model) is None else registry.FORMULA)
    under = registry.get(name)
    assert isinstance(under, PerFrameTier)
    return under
