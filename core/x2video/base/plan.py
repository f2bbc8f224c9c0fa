"""The plan of a render, settled once before any frame is made (`make_plan`): whether the frames go over the shot's own
path-traced rgb (the base, `x2video.base.stage`: its frames `base.fill.BaseFrames`), whether a tier must run at all
and which (`base_choice`, `fill_choice`, else `x2video.tiers.registry.decide`), the order the frames are made in
(`base_order`), the shot as the tiers read it (over the base, a keyframe shot's irradiance supplied by the base's
shading: `base.shading`), and the frames' conditioning, edited and unedited, with the user's reference for a tier
that reads one.

The Renderer keyframes the shot (`x2video.base.keyframes.keyframed`), takes its frame range, makes the plan, and
hands it to `x2video.base.stage.render`, which hands `Plan.job` to the tier: the shot goes forward through the
stages, each visited once.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from x2video.base.fill import BaseFrames
from x2video.base.keyframes import keyframed, reference_keyframes
from x2video.base.shading import ShadedShot, supplies_irradiance
from x2video.base.stage import BASE, Plan
from x2video.conditioning.edited import frame_conditioning, resolve_reference
from x2video.tiers import registry
from x2video.tiers.base import RenderJob, RenderPlan, TierChoice, coarse_to_fine

if TYPE_CHECKING:
    from pathlib import Path

    from x2video.conditioning.cache import ConditioningCache
    from x2video.edits.model import Edits
    from x2video.model.api import RenderModel
    from x2video.render.settings import RenderSettings
    from x2video.render.timing import NoTimes, StageTimes
    from x2video.shot import Shot


def make_plan(shot: Shot, edits: Edits | None, settings: RenderSettings, model: RenderModel | None, frames: tuple[int, int],
              keys: tuple[int, ...], *, cache: ConditioningCache, retain: bool, clock: StageTimes | NoTimes, stats: dict,
              base_dir: str | Path | None = None, bases: BaseFrames | None = None) -> Plan:
    """The plan of a render of frames `frames` of `shot` (keyframed already) with `edits` and `settings` (validated) on
    `model`, `keys` the keyframes fill 'diffusion' reads as references (`keyframes.reference_keyframes`), with the
    Renderer's `cache`, `retain` and `clock`; the tier reports into `stats`. `bases`: the base frames of `shot` kept
    from an earlier render (a new `BaseFrames` where None). Raises ValueError when the tier cannot run
    (`registry.decide`, `fill_choice`) or the reference cannot be read."""
    choice = _base_choice(shot, edits, settings, keys) or _fill_choice(shot, edits, settings, keys)
    filled = choice is not None and choice.tier != BASE  # fill 'diffusion': the tier renders every frame, keyframes as references
    over_base = uses_base(shot, settings) and not filled
    reason = "" if choice is not None or not over_base else f"; over the shot's path-traced frames ({keys_text(shot)})"
    order = base_order(shot, *frames) if over_base else []
    bases = (bases if bases is not None else BaseFrames(shot)) if over_base else None
    supplied = bases is not None and supplies_irradiance(shot)  # over the base, irradiance where the shot lacks it
    rendered = ShadedShot(shot, bases.irradiance) if bases is not None and supplied else shot  # the shot as the tiers read it
    if choice is None:
        choice = registry.decide_supplied(settings.quality, shot, edits, model, ("irradiance",) if supplied else ())
    tier = None if choice.tier == BASE else registry.get(choice.tier)
    why_not = tier.available(model) if filled and tier is not None else None  # (`registry.decide` asks the tiers it decides)
    if why_not is not None:
        raise ValueError(why_not)
    conditioning = frame_conditioning(rendered, edits)
    original = frame_conditioning(rendered, None) if over_base else None
    reference = resolve_reference(shot, edits, base_dir) if edits is not None and tier is not None and tier.reads_reference else None
    job = RenderJob(shot=rendered, edits=edits, settings=settings, choice=choice, model=model, conditioning=clock.wrap("read", conditioning),
                    frames=frames, cache=cache, retain=retain, clock=clock, base_dir=base_dir, reference=reference, stats=stats)
    return Plan(job, tier, over_base, order, bases, original, choice.reason + reason)


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


def base_choice(shot: Shot, edits: Edits | None, settings: RenderSettings) -> TierChoice | None:
    """What a render that runs no tier says it runs (every frame is the base: `uses_base` and `changes_nothing`, and no
    fill 'diffusion'); None when a tier must run, which the tiers decide (`x2video.tiers.registry.decide`). Needs no model."""
    return _base_choice(shot, edits, settings, reference_keyframes(shot, settings))


def _base_choice(shot: Shot, edits: Edits | None, settings: RenderSettings, keys: tuple[int, ...]) -> TierChoice | None:
    if not (uses_base(shot, settings) and changes_nothing(edits)) or keys:
        return None
    return TierChoice(BASE, f"no edits: the shot's path-traced frames ({keys_text(shot)}); base 'off' re-renders them")


def fill_choice(shot: Shot, edits: Edits | None, settings: RenderSettings) -> TierChoice | None:
    """The diffusion tier where it fills a keyframe shot's frames between with every keyframe as a reference
    (`RenderSettings.fill` 'diffusion': `keyframes.reference_keyframes`), else None. ValueError, naming the setting,
    where it cannot: a quality other than 'auto' or 'diffusion', or edits that change pixels. Needs no model."""
    return _fill_choice(shot, edits, settings, reference_keyframes(shot, settings))


def _fill_choice(shot: Shot, edits: Edits | None, settings: RenderSettings, keys: tuple[int, ...]) -> TierChoice | None:
    if not keys:
        return None
    if settings.quality not in ("auto", "diffusion"):
        raise ValueError(f"fill 'diffusion' renders with the diffusion tier, not quality {settings.quality!r}"
                         " (use quality 'auto' or 'diffusion', or fill 'classical')")
    if not changes_nothing(edits):
        raise ValueError("fill 'diffusion' renders a keyframe shot as its keyframes show it, without edits (they would change"
                         " what the keyframes show); render edits with fill 'classical'")
    return TierChoice("diffusion", f"fill 'diffusion': the frames between {len(keys)} keyframes of {shot.num_frames} made by the"
                                   " diffusion tier, every keyframe's path-traced frame a reference (Ref-Keyframe)")


def base_plan(shot: Shot, edits: Edits | None, settings: RenderSettings) -> RenderPlan | None:
    """The plan of a render that runs no tier (`base_choice`): per frame, no model; None when a tier must run."""
    choice = base_choice(shot, edits, settings)
    if choice is None:
        return None
    from x2video.render.settings import frame_range

    return RenderPlan(choice.tier, choice.reason, frame_range(shot, settings), per_frame=True)


def base_order(shot: Shot, start: int, stop: int) -> list[int]:
    """Frames of [start, stop) in the order a render over the base makes them: coarse to fine (`tiers.base.coarse_to_fine`)
    where every frame carries rgb; on a keyframe shot its keyframes first, then the frames between nearest a keyframe
    first (the best filled, as the fill's quality falls with the distance), coarse to fine among equals."""
    order = coarse_to_fine(start, stop)
    keys = np.asarray(shot.keyframes, np.int64)
    if len(keys) == 0 or len(keys) == shot.num_frames:
        return order
    rank = {t: i for i, t in enumerate(order)}
    ts = np.asarray(order, np.int64)
    i = np.clip(np.searchsorted(keys, ts), 1, len(keys) - 1) if len(keys) > 1 else np.zeros_like(ts)
    dist = np.minimum(np.abs(keys[i] - ts), np.abs(keys[np.maximum(i - 1, 0)] - ts))
    return sorted(order, key=lambda t: (int(dist[rank[t]]), rank[t]))


def base_caption(shot: Shot, settings: RenderSettings) -> str:
    """What a render of `shot` with `settings` keeps as its base, in a line for the editor ('' without rgb)."""
    if not base_available(shot):
        return ""
    if settings.base == "off":
        return "Base off: every frame re-rendered from the channels (the shot's path-traced frames unused)"
    return f"Base: the shot's path-traced frames ({keys_text(keyframed(shot, settings))})"


def keys_text(shot: Shot) -> str:
    """Which frames of `shot` carry its rgb, in words: every frame, or how many keyframes of how many frames."""
    keys = shot.keyframes
    if len(keys) == shot.num_frames:
        return "rgb on every frame"
    return f"{len(keys)} keyframes of {shot.num_frames} frames, the rest filled"
