"""Which tier a render runs (docs/ARCHITECTURE.md "Tiers": no more model than a scene needs), and the plan it will run.

    0 formula    albedo x irradiance of the (edited) channels, exact for diffuse light, free (`tiers.formula`);
    1 residual   one deterministic pass of the tier-1 net over it: the glossy term, metals, emitters,
                 windows; per frame, so it cannot flicker (`tiers.residual`);
    2 diffusion  the video diffusion sampler, for what must be generated: a dropped channel, a region
                 whose albedo/material is masked out (A|M|R), a local prompt, a reference (`tiers.diffusion`).

The tiers themselves are classes registered in `x2video.tiers.base.TIERS` (one new class adds one: docs/
ARCHITECTURE.md). `decide` picks one for a render (quality 'auto') and says why; `auto` composites per region:
frames whose channels are all present take tier 1 outside the regions tier 2 must generate (A|M|R regions and
local prompts' masks, `generated_region`), and the two meet over a seam feathered just inside the region (`composite_weight`). The user can
force any tier. `plan_render` is the pure plan of a render: the editor and the farm read it.
"""
from __future__ import annotations

import dataclasses
import logging
from typing import TYPE_CHECKING, Sequence

from x2video.base.shading import SUPPLIED_NOTE, supplies_irradiance
from x2video.channels import INTRINSIC
from x2video.render.settings import RenderSettings, check_pixel_bounds, frame_range
from x2video.tiers.base import TIERS, RenderPlan, Tier, TierChoice
from x2video.tiers.diffusion import DiffusionTier
from x2video.tiers.formula import FormulaTier
from x2video.tiers.residual import ResidualTier

if TYPE_CHECKING:
    from x2video.edits.model import Edits
    from x2video.model.api import RenderModel
    from x2video.shot import Shot

log = logging.getLogger(__name__)

FORMULA, RESIDUAL, DIFFUSION = FormulaTier.name, ResidualTier.name, DiffusionTier.name


def qualities() -> tuple[str, ...]:
    """What `RenderSettings.quality` accepts: 'auto' and every registered tier."""
    return ("auto", *TIERS)


#: the built-in qualities (the CLI's choices; `qualities()` adds tiers registered later)
QUALITIES = ("auto", FORMULA, RESIDUAL, DIFFUSION)


def get(name: str) -> Tier:
    """The registered tier `name` (ValueError naming the choices when there is none)."""
    cls = TIERS.get(name)
    if cls is None:
        raise ValueError(f"unknown quality {name!r} (use one of {', '.join(qualities())})")
    return cls()


def generative(name: str | None) -> bool:
    """Whether `name` is a registered tier that generates what the channels do not say (`Tier.generative`); False
    for '', None, 'auto' and names no tier has."""
    cls = TIERS.get(name or "")
    return cls is not None and cls.generative


def windowed(name: str | None) -> bool:
    """Whether `name` is a registered tier that renders in windows (not `Tier.per_frame`): the sampler's steps, its preset
    and its engine are this tier's; False for '', None, 'auto' and names no tier has."""
    cls = TIERS.get(name or "")
    return cls is not None and not cls.per_frame


#: channels the formula (albedo x irradiance) does not read: auto renders tier 0 when only these are missing
FORMULA_IGNORES = ("normal", "roughness", "metallic")


def needs_model(quality: str) -> bool:
    """Whether a render at `quality` needs a model: 'auto' does (its choice depends on the model), a forced tier says."""
    return quality == "auto" or get(quality).needs_model


def dropped_channels(shot, edits, supplied: Sequence[str] = ()) -> list[str]:
    """The intrinsic channels the shot lacks (on some frame) or the edits drop, in `INTRINSIC` order; `supplied`: channels
    a render supplies where the shot lacks them (`supplied_channels`), which count as present unless dropped."""
    return [n for n in INTRINSIC if (not shot.has(n) and n not in supplied) or (edits is not None and n in edits.dropped)]


def supplied_channels(shot, base: str = "auto") -> tuple[str, ...]:
    """The channels a render of `shot` with `RenderSettings.base` = `base` supplies where the shot lacks them: irradiance
    on a keyframe shot's frames without it, from the base's shading, when the render goes over the base
    (`x2video.base.shading`)."""
    return ("irradiance",) if base == "auto" and supplies_irradiance(shot) else ()


def decide(quality: str, shot: Shot, edits: Edits | None, model: RenderModel | None, base: str = "auto") -> TierChoice:
    """The tier a render of `shot` with `edits` (or None) runs on `model` (None: no model) at `quality`: `choose_tier`
    given `generation_reasons`, the channels missing, the model's tier-1 net and its record; ValueError when the tier
    cannot run with `model` (`Tier.available`). `base`: the render's `RenderSettings.base` (over the base, a keyframe
    shot's irradiance is supplied where it lacks it: `supplied_channels`). The Renderer, its `prepare` and
    `plan_render` all ask here."""
    return decide_supplied(quality, shot, edits, model, supplied_channels(shot, base))


def decide_supplied(quality: str, shot: Shot, edits: Edits | None, model: RenderModel | None, supplied: Sequence[str] = ()) -> TierChoice:
    """`decide`, told which channels the render supplies where the shot lacks them (`supplied_channels`): what a render's
    plan asks, which knows whether the render goes over the base (`x2video.base.plan`)."""
    reasons, only_regions = generation_reasons(shot, edits, supplied)
    choice = choose_tier(quality, reasons, only_regions, model is not None and model.residual_net is not None,
                         "" if edits is None else edits.global_prompt, residual_trusted=model is None or bool(model.residual_auto),
                         dropped=dropped_channels(shot, edits, supplied))
    why_not = get(choice.tier).available(model)
    if why_not is not None:
        raise ValueError(why_not)
    if supplied and (edits is None or "irradiance" not in edits.dropped):
        choice = dataclasses.replace(choice, reason=f"{choice.reason}; {SUPPLIED_NOTE}")
    return choice


def plan_render(shot: Shot, edits: Edits | None, settings: RenderSettings, model: RenderModel | None) -> RenderPlan:
    """What a render of `shot` with `edits` and `settings` on `model` runs: its tier and why, its frames, and for a
    windowed tier its windows and steps. Pure: read from the edits' structure and the settings, nothing encoded."""
    frames = frame_range(shot, settings)
    check_pixel_bounds(settings)
    choice = decide(settings.quality, shot, edits, model, settings.base)
    return get(choice.tier).plan(shot, edits, settings, model, choice, frames)


def estimate_plan(shot: Shot, edits: Edits | None, settings: RenderSettings) -> RenderPlan:
    """The plan before the model is built (the editor's first render): a forced tier's own plan where it needs no
    model, else the diffusion tier's for a model without LCM weights; RenderStarted and StepDone correct it."""
    if not needs_model(settings.quality):
        return plan_render(shot, edits, settings, None)
    frames = frame_range(shot, settings)
    return DiffusionTier().plan(shot, edits, settings, None, TierChoice(DIFFUSION, "estimated before the model is built"), frames)


def generation_reasons(shot, edits, supplied: Sequence[str] = ()) -> tuple[list[str], bool]:
    """(why a render of `shot` with `edits` (or None) needs the diffusion sampler, whether that is only
    inside masked regions of frames that otherwise have every channel). Read from the edits'
    structure, not the pixels, so deciding costs nothing on a 1,000-frame shot. `supplied`: as `dropped_channels`."""
    from x2video.edits.ops import MaskOut

    why: list[str] = []
    dropped = dropped_channels(shot, edits, supplied)
    if dropped:
        why.append(f"channel(s) {', '.join(dropped)} missing or dropped")
    if edits is None:
        return why, False
    outs = [op for op in edits.ops if isinstance(op, MaskOut)]
    if any(op.mask is None for op in outs):
        why.append("albedo/material masked out on whole frames")
    regional = [op for op in outs if op.mask is not None]
    if regional:
        why.append(f"albedo/material masked out (A|M|R) inside mask(s) {', '.join(sorted({op.mask for op in regional}))}")
    local = edits.local_prompt_masks()
    if local:
        why.append(f"local prompt(s) on {', '.join(local)}")
    if edits.reference is not None:
        why.append("a reference frame to follow")
    # A|M|R inside masks and local prompts act inside their masks only (Masked Cross-Attention confines a local
    # prompt to its mask): around them the frame is what auto renders with nothing to generate. The sampler still
    # sees whole frames; `generated_region` says where its pixels are kept.
    regions = bool(regional) + bool(local)
    only_regions = regions > 0 and len(why) == regions
    return why, only_regions


def choose_tier(quality: str, reasons: list[str], only_regions: bool, has_residual: bool, global_prompt: str = "",
                residual_trusted: bool = True, dropped: Sequence[str] = ()) -> TierChoice:
    """The tier a render runs at `quality` ("auto" or a forced tier), given `generation_reasons`.
    `residual_trusted`: whether the tier-1 net's own record (residual.json "auto") says it beat the formula on the
    validation rooms (its "auto_decided_on"); where it does not, auto renders what needs nothing generated with the
    formula.
    `dropped`: the channels missing; when they are only ones the formula ignores (`FORMULA_IGNORES`) and
    nothing else asks for generation, auto renders the formula. Decided on 6 v3 validation rooms against their truth
    apart (`python -m bench.stability --data DATA/v3val6/val --families channels`, bench/results/stability/
    stability_v3val6.json): on those 7 subsets the diffusion tier and tier 1 (forced; trained on all five channels)
    are above the formula on 6 but 3.2 and 4.1 dB under it without roughness (albedo, normal, metallic, irradiance);
    only the formula keeps auto's promise on all 7. (The earlier reason, the diffusion tier 0.4-7.4 dB below the
    formula on all 7, was measured on test rooms with earlier weights.) A model without a tier-1 net keeps the
    paper's behaviour: the sampler for anything missing."""
    if quality not in qualities():
        raise ValueError(f"unknown quality {quality!r} (use one of {', '.join(qualities())})")
    if quality == "residual" and not has_residual:
        raise ValueError("quality 'residual' needs the tier-1 network (residual.safetensors beside the weights);"
                         " the loaded model has none")
    if quality != "auto":
        return TierChoice(quality, "forced by the user")
    if not has_residual:
        return TierChoice("diffusion", "this model has no tier-1 network")
    if dropped and set(dropped) <= set(FORMULA_IGNORES) and len(reasons) == 1:
        return TierChoice("formula", f"{reasons[0]}: albedo x irradiance needs neither; the diffusion tier renders below it"
                                     " without them (force 'diffusion' to generate them)")
    if not reasons:
        note = "; a global prompt alone does not change that (quality 'diffusion' follows it)" if global_prompt else ""
        if not residual_trusted:
            return TierChoice("formula", f"every channel present, nothing to generate{note}; this tier-1 net measured below the"
                                         " formula on the validation rooms, so auto keeps the formula (force 'residual' to use it)")
        return TierChoice("residual", f"every channel present, nothing to generate{note}")
    if only_regions:  # generate only inside the regions; around them what auto would render with nothing to generate
        if residual_trusted:
            return TierChoice("diffusion", f"{'; '.join(reasons)}: generated there, tier 1 around it", base="residual", regions=True)
        return TierChoice("diffusion", f"{'; '.join(reasons)}: generated there, the formula around it", base="formula", regions=True)
    return TierChoice("diffusion", "; ".join(reasons))

