"""Tiers: no more model than a scene needs (DESIGN.md, "Tiers").

    0 formula    albedo x irradiance of the (edited) channels, exact for diffuse light, free;
    1 residual   one deterministic pass of the tier-1 net (`x2video.model.residual`) over it: the
                 glossy term, metals, emitters, windows; per frame, so it cannot flicker;
    2 diffusion  the video diffusion sampler, for what must be generated: a dropped channel,
                 a region whose albedo/material is masked out (A|M|R), a local prompt, a reference.

`choose_tier` decides for a render (quality "auto") and says why; `auto` composites per region:
frames whose channels are all present take tier 1 outside the regions tier 2 must generate (A|M|R
regions and local prompts' masks, `generated_region`), and the two meet over a feathered seam
(`feathered`). The user can force any tier.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from x2video.channels import INTRINSIC
from x2video.conditioning import FrameConditioning

log = logging.getLogger(__name__)

QUALITIES = ("auto", "formula", "residual", "diffusion")
#: pixels of the feather between a generated region (tier 2) and its surroundings (tier 1)
FEATHER_PX = 6.0


@dataclass(frozen=True)
class TierChoice:
    """What a render runs: `tier` for the frames, and `regions` True when tier 2 runs only inside
    the generated regions of frames that otherwise have every channel (composited over `base`)."""

    tier: str
    reason: str
    base: str = ""
    regions: bool = False


#: channels the formula (albedo x irradiance) does not read: auto renders tier 0 when only these are missing
FORMULA_IGNORES = ("normal", "roughness", "metallic")


def dropped_channels(shot, edits) -> list[str]:
    """The intrinsic channels the shot lacks or the edits drop, in `INTRINSIC` order."""
    return [n for n in INTRINSIC if not shot.has(n) or (edits is not None and n in edits.dropped)]


def decide(quality: str, shot, edits, model) -> TierChoice:
    """The tier a render of `shot` with `edits` (or None) runs on `model` at `quality`: `choose_tier` given
    `generation_reasons`, the channels missing, the model's tier-1 net and its record. The Renderer and its
    `prepare` both ask here."""
    reasons, only_regions = generation_reasons(shot, edits)
    return choose_tier(quality, reasons, only_regions, getattr(model, "residual_net", None) is not None,
                       "" if edits is None else edits.global_prompt, residual_trusted=bool(getattr(model, "residual_auto", True)),
                       dropped=dropped_channels(shot, edits))


def generation_reasons(shot, edits) -> tuple[list[str], bool]:
    """(why a render of `shot` with `edits` (or None) needs the diffusion sampler, whether that is only
    inside masked regions of frames that otherwise have every channel). Read from the edits'
    structure, not the pixels, so deciding costs nothing on a 1,000-frame shot."""
    from x2video.edits.ops import MaskOut

    why: list[str] = []
    dropped = dropped_channels(shot, edits)
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


def generated_region(cond: FrameConditioning) -> np.ndarray:
    """(H, W) bool: where a regional render keeps the sampler's pixels: the frame's A|M|R regions and its local
    prompts' masks (> 0.5)."""
    region = np.asarray(cond.amr_mask, np.float32) > 0.5
    if cond.local_masks.size:
        region = region | (np.asarray(cond.local_masks, np.float32) > 0.5).any(0)
    return region


def choose_tier(quality: str, reasons: list[str], only_regions: bool, has_residual: bool, global_prompt: str = "",
                residual_trusted: bool = True, dropped: Sequence[str] = ()) -> TierChoice:
    """The tier a render runs at `quality` ("auto" or a forced tier), given `generation_reasons`.
    `residual_trusted`: whether the tier-1 net's own record (residual.json "auto") says it beat the formula on
    the outside check; where it does not, auto renders what needs nothing generated with the formula.
    `dropped`: the channels missing; when they are only ones the formula ignores (`FORMULA_IGNORES`) and
    nothing else asks for generation, auto renders the formula: the diffusion tier measured 0.4-7.4 dB below it
    on all 7 such subsets (docs/STABILITY.md, channel subsets), and the tier-1 net is trained on all five channels. A model
    without a tier-1 net keeps the paper's behaviour: the sampler for anything missing."""
    if quality not in QUALITIES:
        raise ValueError(f"unknown quality {quality!r} (use one of {', '.join(QUALITIES)})")
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
                                         " formula on the outside scenes, so auto keeps the formula (force 'residual' to use it)")
        return TierChoice("residual", f"every channel present, nothing to generate{note}")
    if only_regions:  # generate only inside the regions; around them what auto would render with nothing to generate
        if residual_trusted:
            return TierChoice("diffusion", f"{'; '.join(reasons)}: generated there, tier 1 around it", base="residual", regions=True)
        return TierChoice("diffusion", f"{'; '.join(reasons)}: generated there, the formula around it", base="formula", regions=True)
    return TierChoice("diffusion", "; ".join(reasons))


def formula_frame(cond: FrameConditioning) -> np.ndarray:
    """Tier 0: (H, W, 3) linear albedo x irradiance of one frame's (edited) channels, zero inside A|M|R regions.

    The plain product, not `x2video.model.shading.classical_shading`, whose grey-world GGX term
    overshoots a path tracer's energy-conserving BSDF (`x2video.model.residual`)."""
    from x2video.model.residual import formula

    out = formula(cond.channels, np.shape(cond.amr_mask)[:2] if np.size(cond.amr_mask) else None)
    return out * (np.asarray(cond.amr_mask, np.float32) <= 0.5)[..., None] if cond.amr_mask.size else out


@torch.inference_mode()
def residual_frames(net, conds: Sequence[FrameConditioning], device: torch.device | str = "cpu", batch: int = 4,
                    guess_unseen: bool = False, max_pixels: int = 0) -> list[np.ndarray]:
    """Tier 1: (H, W, 3) linear frames from the tier-1 net, up to `batch` frames per pass and never more than
    `residual.MAX_PIXELS` pixels in one: a frame larger than that runs in overlapping tiles (`residual.apply_tiled`,
    equal to the whole-frame pass to float precision), so the net's working memory does not grow with the frame.
    A frame with more than `max_pixels` pixels (`RenderSettings.residual_pixels`; 0: none) runs the net at a
    working size of at most that many (`working.working_size`, channels area-averaged); the net's log-space
    correction of the formula there (`residual.correction`) comes back to full size bilinearly and is added to
    the full-resolution formula in log space, so the formula's detail stays full resolution.
    Unless `guess_unseen`, pixels whose channels say nothing of their light (`residual.unseen_light`: sky, clear
    glass, mirrors) keep the formula instead of the net's guess (decided at full resolution; at a working size the
    correction is also 0 on such working pixels and next to them, so the guess does not spread when upsampled)."""
    from x2video.model.residual import formula
    from x2video.sampling import working

    sizes = [working.working_size(_size(c), net.cfg.factor, max_pixels) if max_pixels else None for c in conds]
    frames: list[np.ndarray] = [np.empty(0)] * len(conds)
    whole = [i for i, ws in enumerate(sizes) if ws is None]
    for i, f in zip(whole, _net_frames(net, [conds[i] for i in whole], device, batch)):
        frames[i] = f
    small = [i for i, ws in enumerate(sizes) if ws is not None]
    lows = [working.downsample_conditioning(conds[i], sizes[i]) for i in small]
    for i, low, r in zip(small, lows, _net_frames(net, lows, device, batch, corrections=True)):
        if not guess_unseen:  # upsampled, the guess would spread a working pixel onto the lit surfaces around
            r = _without_unseen(r, low)  # windows and mirrors (a bright rim): no correction there or next to it
        frames[i] = working.onto_formula(r, formula(conds[i].channels, _shape(conds[i])))
    return frames if guess_unseen else [keep_formula_where_unseen(f, c.channels) for f, c in zip(frames, conds)]


def _without_unseen(r: np.ndarray, low: FrameConditioning) -> np.ndarray:
    """A working-size correction `r` (h, w, 3) set to 0 where `low`'s channels hold no light and one pixel around."""
    import cv2

    from x2video.model.residual import unseen_light

    m = unseen_light(low.channels, r.shape[:2])
    if m is None or not m.any():
        return r
    near = cv2.dilate(m.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return np.where(near[..., None], 0, r).astype(np.float32)


def _shape(c: FrameConditioning) -> tuple[int, int] | None:
    return tuple(np.shape(c.amr_mask)[:2]) if np.size(c.amr_mask) else None  # type: ignore[return-value]


def _size(c: FrameConditioning) -> tuple[int, int]:
    return _shape(c) or next(np.shape(v)[:2] for v in c.channels.values() if v is not None)


def _net_frames(net, conds: Sequence[FrameConditioning], device: torch.device | str, batch: int,
                corrections: bool = False) -> list[np.ndarray]:
    """The net's own output for each frame (`residual_frames` without the unseen-light rule), or with `corrections`
    its log-space correction of the formula (before the output is clipped at 0)."""
    from x2video.model.residual import MAX_PIXELS, apply, apply_tiled, correction, features, formula, needs_tiles

    shape, size = _shape, _size
    out: list[np.ndarray] = []
    i = 0
    while i < len(conds):
        hw = size(conds[i])
        if needs_tiles(hw, net.cfg.factor):
            f = apply_tiled(net, conds[i].channels, shape(conds[i]))
            if corrections:  # (a working size beyond one tile: the clipped output's correction)
                f = np.log1p(np.maximum(f, 0)) - np.log1p(np.maximum(formula(conds[i].channels, shape(conds[i])), 0))
            out.append(f)
            i += 1
            continue
        n = max(1, min(batch, MAX_PIXELS // (hw[0] * hw[1])))
        group = [conds[i]]
        while len(group) < n and i + len(group) < len(conds) and size(conds[i + len(group)]) == hw:
            group.append(conds[i + len(group)])
        feats = [features(c.channels, shape(c)) for c in group]
        x = torch.from_numpy(np.stack([f[0] for f in feats])).to(device)  # (B, C_in, H, W)
        s = torch.from_numpy(np.stack([f[1] for f in feats])).to(device)  # (B, 3, H, W)
        y = (correction(net, x) if corrections else apply(net, x, s)).permute(0, 2, 3, 1).float().cpu().numpy()  # (B, H, W, 3)
        out.extend(np.ascontiguousarray(f) for f in y)
        i += len(group)
    return out


def keep_formula_where_unseen(frame: np.ndarray, channels, px: float = 2.0) -> np.ndarray:
    """`frame` (H, W, 3, a tier-1 render) with the formula where `residual.unseen_light` says the channels hold
    nothing of the light, blended over `px` pixels beyond (`feathered`), so the net's halo at the edge goes too."""
    from x2video.model.residual import formula, unseen_light

    m = unseen_light(channels, frame.shape[:2])
    if m is None or not m.any():
        return frame
    w = feathered(m, px)[..., None]
    return (w * formula(channels, frame.shape[:2]) + (1 - w) * frame).astype(np.float32)


def feathered(mask: np.ndarray, px: float = FEATHER_PX) -> np.ndarray:
    """(H, W) weights in [0, 1]: the mask grown by `px` pixels, then blurred within `px` (a Gaussian of
    sigma px/2 truncated at 2 sigma): 1 inside the mask, exactly 0 farther than 2 px from it."""
    import cv2

    m = (np.asarray(mask, np.float32) > 0.5).astype(np.float32)
    if px <= 0 or not m.any():
        return m
    k = int(2 * round(px) + 1)
    grown = cv2.dilate(m, np.ones((k, k), np.uint8))
    return np.clip(cv2.GaussianBlur(grown, (k, k), px / 2, borderType=cv2.BORDER_REPLICATE), 0, 1)


def coarse_to_fine(start: int, stop: int) -> list[int]:
    """Frames of [start, stop) in the order a timeline fills best: ends first, then halves recursively."""
    order, seen = [], set()
    span = 1
    while span < stop - start:
        span *= 2
    while span >= 1:
        for f in range(start, stop, span):
            if f not in seen:
                seen.add(f)
                order.append(f)
        span //= 2
    if stop - 1 not in seen:
        order.insert(1, stop - 1)
    return order
