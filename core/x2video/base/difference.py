"""Edits as differences over the base: Debevec's differential rendering, out = base + R(edited) - R(original).

R is a tier's render of a frame's channels; its systematic errors (light the five channels do not hold: sky, lamps,
mirrors, glass) appear in both renders and cancel, so the base keeps them. An edit reaches the pixels whose
channels it changed, plus a margin for the light it spills onto its surroundings (`reach`); every other pixel is
the base, bit for bit.

What the base stage (`x2video.base.stage`) does to each frame an edit reaches is this module's job, in one call:
`edited_frame` for the per-frame tiers (which pixels changed, tier 0's part rebuilt from the passes,
`x2video.base.passes`, tier 1's glossy part, the light spread into a metal made non-metal), `generated_frame` for a
tier that generates its frames.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Callable, Literal

import cv2
import numpy as np

from x2video.base.passes import rebuild
from x2video.channels import INTRINSIC
from x2video.conditioning.frame import FrameConditioning

#: what `RenderStarted.tier` and `FramesReady.mode` say for frames that are the base with no tier's change
BASE = "base"
#: pixels around an edit where its spill (a red sofa tints the floor beside it) may change the frame
SPILL_MARGIN = 6
#: channels whose change only a network's difference renders (the glossy term)
GLOSSY_CHANNELS = ("normal", "roughness", "metallic")
#: the same where the frame has Cycles' glossy colour pass: a metallic edit is then the rebuild from the passes
#: (`x2video.base.passes`: the diffuse and glossy colours change, their light stays). On the validation rooms, metal
#: made non-metal and back: the rebuild 23.8 / 27.2 dB and 29.6 / 26.0 inside the object, tier 1's difference 18.6 /
#: 32.6 and 22.1 / 32.8: a tie on the mean, and the rebuild's worst (23.8) above doing nothing's (22.9) where tier 1's
#: (18.6) fell 4 dB below it
GLOSSY_CHANNELS_WITH_PASSES = ("normal", "roughness")

Mode = Literal["difference", "ratio"]
#: how an edit's change goes over the base: "auto" (`LIGHT_MODE` where an edit changed only the light, `MATERIAL_MODE`
#: elsewhere), or one of `Mode` everywhere (what bench.edits measures against auto)
HowOver = Literal["auto", "difference", "ratio"]
#: where an edit changed only the light: a ratio. A light edit scales every term of the rebuild (`x2video.base.passes`),
#: so base x R(edited) / R(original) is the base times the light's gain, exact where Cycles' light is linear in its
#: lamps, whatever the passes miss; a difference adds the gain to the rebuild only (on the validation room's global
#: light edit the rebuild, base x gain, scored 55.3 dB on the whole frame, a difference of diffuse light alone 21.8)
LIGHT_MODE: Mode = "ratio"
#: where an edit changed albedo, roughness, metallic or normal: a difference (albedo: 32.6 dB inside on the validation
#: room, the compositor's rebuild 32.4; a ratio 13.6, since it multiplies the light the formula lacks, a highlight, by
#: the albedo's change)
MATERIAL_MODE: Mode = "difference"
#: channels whose change is a change of material (the rest, irradiance and the light passes, are light)
MATERIAL_CHANNELS = ("albedo", "normal", "roughness", "metallic")


def changed(original: FrameConditioning, edited: FrameConditioning, names: tuple[str, ...] = INTRINSIC) -> np.ndarray:
    """(H, W) bool: pixels where any of `names` differs between the two conditionings (a channel present in one and
    dropped in the other changes every pixel); with every intrinsic channel (the default) also those where a pass
    differs (a light edit of an emitter or the sky: no irradiance there) or that an A|M|R mask or local prompt covers."""
    h, w = edited.size
    out = np.zeros((h, w), bool)
    for name in names:
        a, b = original.channels.get(name), edited.channels.get(name)
        if a is None and b is None:
            continue
        if a is None or b is None:
            return np.ones((h, w), bool)
        out |= pixels_differ(a, b)
    if names == INTRINSIC:
        out |= passes_changed(original, edited)
        if np.size(edited.amr_mask):
            out |= np.asarray(edited.amr_mask) > 0.5
        if np.size(edited.local_masks):
            out |= np.asarray(edited.local_masks).max(0) > 0
    return out


def pixels_differ(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels where two (H, W, C) arrays differ in any component (an elementwise or of the C planes: numpy's
    reduction over a short last axis is several times slower, and a live preview computes this a few times a frame)."""
    d = np.asarray(a) != np.asarray(b)
    if d.ndim == 2:
        return d
    return functools.reduce(np.logical_or, [d[..., c] for c in range(d.shape[-1])])


def passes_changed(original: FrameConditioning, edited: FrameConditioning) -> np.ndarray:
    """(H, W) bool: pixels where a pass differs (a light operation scaled it); every pixel where one frame has a pass
    the other lacks."""
    h, w = edited.size
    out = np.zeros((h, w), bool)
    for name in set(original.passes) | set(edited.passes):
        a, b = original.passes.get(name), edited.passes.get(name)
        if a is None or b is None:
            return np.ones((h, w), bool)
        out |= pixels_differ(a, b)
    return out


def grow(mask: np.ndarray, px: int) -> np.ndarray:
    """`mask` (H, W) bool dilated by `px` pixels (a disc)."""
    if px <= 0 or not mask.any():
        return mask
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * px + 1, 2 * px + 1))
    return cv2.dilate(mask.astype(np.uint8), k).astype(bool)


def reach(original: FrameConditioning, edited: FrameConditioning, margin: int = SPILL_MARGIN) -> np.ndarray:
    """(H, W) bool: the pixels an edit may change: what it changed, grown by `margin` for its spill."""
    return grow(changed(original, edited), margin)


def feathered_reach(original: FrameConditioning, edited: FrameConditioning, margin: int = SPILL_MARGIN) -> np.ndarray | None:
    """(H, W) float32 weight of a generated frame over the base: 1 on what the edit changed, falling to 0 across the
    spill margin (a distance ramp), 0 beyond; None when the edit changes nothing in this frame."""
    core = changed(original, edited)
    if not core.any():
        return None
    dist = cv2.distanceTransform((~core).astype(np.uint8), cv2.DIST_L2, 3)
    return np.clip(1.0 - dist / max(margin, 1), 0.0, 1.0).astype(np.float32)


def generated_frame(base: np.ndarray, generated: np.ndarray, original: FrameConditioning, edited: FrameConditioning,
                    unedited: Callable[[], np.ndarray] | None = None, margin: int = SPILL_MARGIN) -> np.ndarray:
    """One frame of a tier that generates (the diffusion sampler) over the base (H, W, 3): inside the edit's reach,
    weighted by `feathered_reach` (w), its frame G = `generated` replaces the base, w G + (1 - w) B, or with `unedited`
    (called only where the edit reaches the frame: R, a per-frame tier's frame of the unedited channels) goes over it
    as a difference, B + w (G - R), never below 0; `base` bit for bit everywhere else (the whole frame where the edit
    changes nothing in it)."""
    w = feathered_reach(original, edited, margin)
    if w is None:
        return base
    w3 = w[..., None]  # (H, W, 1)
    if unedited is None:
        new = w3 * generated + (1 - w3) * base
    else:
        new = np.maximum(base + w3 * (np.asarray(generated, np.float64) - unedited()), 0.0)
    return np.where(w3 > 0, new, base)


def light_only(original: FrameConditioning, edited: FrameConditioning) -> np.ndarray:
    """(H, W) bool: pixels where the edit changed only the light (irradiance or a light pass), no material channel,
    mask or local prompt."""
    material = changed(original, edited, MATERIAL_CHANNELS)
    if np.size(edited.amr_mask):
        material |= np.asarray(edited.amr_mask) > 0.5
    if np.size(edited.local_masks):
        material |= np.asarray(edited.local_masks).max(0) > 0
    return changed(original, edited) & ~material


def over_base(base: np.ndarray, r_edited: np.ndarray, r_original: np.ndarray, where: np.ndarray, mode: Mode = "difference") -> np.ndarray:
    """The base (H, W, 3, float64) with the edit's change inside `where`: base + R(edited) - R(original), or as a ratio
    base x R(edited) / R(original) (the difference where R(original) is black); never below 0. Outside `where` the
    base's values are returned untouched."""
    e, o = np.asarray(r_edited, np.float64), np.asarray(r_original, np.float64)
    if mode == "ratio":
        new = np.where(o > 1e-6, base * (e / np.maximum(o, 1e-6)), base + (e - o))
    else:
        new = base + (e - o)
    new = np.maximum(new, 0.0, out=new)
    return new if where.all() else np.where(where[..., None], new, base)


def spread_into(values: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """`values` (H, W, C) with the pixels of `hole` (H, W) filled from the pixels around them: normalised convolution at
    growing Gaussian scales (the nearest known values weigh most), in log space so light levels blend as exposures."""
    if not hole.any():
        return values
    known = (~hole).astype(np.float32)
    if not known.any():
        return values
    logs = np.log1p(np.maximum(values, 0)).astype(np.float32) * known[..., None]
    out = np.zeros_like(logs)
    todo = hole.copy()
    sigma = 1.0
    while todo.any():
        num = cv2.GaussianBlur(logs, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        den = cv2.GaussianBlur(known, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        ok = todo & (den > 1e-3)
        out[ok] = num[ok] / den[ok][:, None]
        todo &= ~ok
        sigma *= 2
        if sigma > 4 * max(hole.shape):
            out[todo] = logs[known > 0].mean(0)
            break
    return np.where(hole[..., None], np.expm1(out), values).astype(np.float32)


#: irradiance below this fraction of the frame's median says no diffuse light was measured (a pure metal's)
NO_LIGHT = 1e-3


def relit_metal(original: FrameConditioning, edited: FrameConditioning) -> FrameConditioning:
    """`edited` with the diffuse light inferred where a metal was made non-metal: Cycles' diffuse passes are black on a
    metal (no diffuse lobe), and a pixel partly metal (a filtered edge, metallic between 0 and 1) holds only the
    diffuse part's light. Where the frame has the glossy passes (glossy and glossy_color), the light the metal's
    glossy lobe gathered (glossy / GlossCol: Cycles' GlossDir + GlossInd) stands for the missing part:
    irradiance + metallic x gathered. On the validation rooms' brass desk and black cabinet that scored 23.8 and
    27.2 dB inside the object, against 18.8 and 27.2 with the gathered light on unlit pixels only, and 15.2 and 26.2
    for light spread in from the surfaces around (`spread_into`: the desk's neighbours in the picture lie in its
    shadow); the spread is the fallback without the glossy passes, on the pixels that measured no diffuse light."""
    mo, me, irr = original.channels.get("metallic"), edited.channels.get("metallic"), edited.channels.get("irradiance")
    if mo is None or me is None or irr is None:
        return edited
    moved = (np.asarray(mo)[..., 0] > 0.5) & (np.asarray(me)[..., 0] <= 0.5)
    if not moved.any():
        return edited
    irr = np.asarray(irr, np.float32)
    channels = dict(edited.channels)
    gloss, gc = edited.passes.get("glossy"), edited.passes.get("glossy_color")
    if gloss is not None and gc is not None:
        gathered = np.asarray(gloss, np.float32) / np.maximum(np.asarray(gc, np.float32), 1e-3)
        m = np.clip(np.asarray(mo, np.float32), 0, 1)
        channels["irradiance"] = np.where(grow(moved, 1)[..., None], irr + m * gathered, irr).astype(np.float32)
    else:
        lum = irr.mean(-1)
        hole = moved & (lum <= NO_LIGHT * max(float(np.median(lum)), 1e-6))
        if not hole.any():
            return edited
        channels["irradiance"] = spread_into(irr, grow(hole, 1))
    return dataclasses.replace(edited, channels=channels)


def sharpened(original: FrameConditioning, edited: FrameConditioning) -> np.ndarray:
    """(H, W) bool: pixels an edit made glossier (roughness down) and changed in no other glossy channel (normal,
    metallic): where tier 1's difference is not used (`edited_frame`). A sharper reflection shows
    the light arriving from the mirror direction, which none of the pixel's channels holds (the base holds it only
    blurred by the old roughness): the net can only guess it, and on the validation room its guess, a rough object
    made glossy, scored 25.4 dB inside the object against doing nothing's 30.0. The formula's difference there is
    doing nothing (roughness is not in the formula), which that figure says is the better floor. A rougher
    surface (the reflection blurred) needs no such guess: tier 1 keeps it (the issue's floor, 34.7 against 31.4)."""
    ro, re = original.channels.get("roughness"), edited.channels.get("roughness")
    if ro is None or re is None:
        return np.zeros(edited.size, bool)
    down = np.asarray(re)[..., 0] < np.asarray(ro)[..., 0]
    return down & ~changed(original, edited, ("normal", "metallic"))


#: tier 1's frames of (edited, original) that `edited_frame` needs inside a (H, W) bool mask: (H, W, 3) each, anything
#: outside it (`x2video.base.tier1.residual_difference`: the net on the box around it)
Residual = Callable[["FrameConditioning", "FrameConditioning", np.ndarray], tuple[np.ndarray, np.ndarray]]


def edited_frame(base: np.ndarray, original: FrameConditioning, edited: FrameConditioning, *, glossy_tier: bool,
                 residual: Residual | None, margin: int = SPILL_MARGIN,
                 mode: HowOver = "auto", sharpen: bool = False, learned: bool = False) -> tuple[np.ndarray, str]:
    """One frame: `base` (model exposure, float64) with the edit's changes, and which tiers made them.

    Tier 0's R is the frame rebuilt from its passes (`base.passes.rebuild`: the compositor's rebuild where the shot has
    Cycles' passes, albedo x irradiance where it has not), over the base as a ratio where the edit changed only the
    light and as a difference elsewhere (mode "auto": `LIGHT_MODE`, `MATERIAL_MODE`; or one mode
    everywhere). Tier 1's difference replaces it where roughness, metallic or normal changed (`glossy_tier` with a
    `residual`), except where a surface was only made glossier (`sharpened`; `sharpen` takes tier 1's
    there too, for measuring). With `learned` (a difference net's `residual`: its frames are its residual over the formula,
    `x2video.train.difference_stage`) tier 0's rebuild renders the whole reach and the net's residual difference is
    added wherever a material channel changed (albedo, normal, roughness, metallic), within the spill margin, but
    where a surface was only made glossier (as above)."""
    everything = changed(original, edited)
    if not everything.any():
        return base, BASE
    reach = grow(everything, margin)
    relit = relit_metal(original, edited)  # on the whole frame: it spreads the light in from around the hole
    rows, cols = _box(reach)  # from here on the work is per pixel: only the box around the reach is computed
    o, e, e_relit, reach_box = original.cropped(rows, cols), edited.cropped(rows, cols), relit.cropped(rows, cols), reach[rows, cols]
    b = base[rows, cols]
    glossy = np.zeros(reach_box.shape, bool)  # where tier 1's difference is taken
    if learned and glossy_tier and residual is not None:
        material = changed(o, e_relit, MATERIAL_CHANNELS)
        if not sharpen:  # a sharper highlight is a guess for the difference net too (validation pairs: -1.0 dB on gloss)
            material &= ~sharpened(o, e_relit)
        glossy = grow(material, margin) & reach_box
    elif glossy_tier and residual is not None:
        glossy_changed = changed(o, e_relit, GLOSSY_CHANNELS_WITH_PASSES if "glossy_color" in o.passes else GLOSSY_CHANNELS)
        if not sharpen:
            glossy_changed &= ~sharpened(o, e_relit)
        glossy = grow(glossy_changed, margin) & reach_box
    out, rest = b, reach_box if learned else reach_box & ~glossy  # tier 0's difference everywhere else in the reach (all of it under a difference net)
    if rest.any():
        r_e, r_o = rebuild(e_relit, o), rebuild(o, o)
        light = light_only(o, e) & rest if mode == "auto" else None
        if light is None:
            out = over_base(b, r_e, r_o, rest, mode)  # type: ignore[arg-type]
        else:
            out = over_base(b, r_e, r_o, rest & ~light, MATERIAL_MODE)
            out = np.where(light[..., None], over_base(b, r_e, r_o, light, LIGHT_MODE), out)
    made = "formula"
    if glossy.any():
        wanted = np.zeros(reach.shape, bool)
        wanted[rows, cols] = glossy
        r_e, r_o = (r[rows, cols] for r in residual(relit, original, wanted))  # type: ignore[misc]
        if learned:  # the net's residual difference over tier 0's frame
            out = np.where(glossy[..., None], np.maximum(out + (r_e - r_o), 0.0), out)
        else:  # over `out`, the base bit for bit inside `glossy` (tier 0's difference went only where it is not)
            out = over_base(out, r_e, r_o, glossy, MATERIAL_MODE if mode == "auto" else mode)  # type: ignore[arg-type]
        made = "formula+residual"
    if out is not b and out.shape == base.shape:  # the edit reaches the whole frame: `out` is a new frame already
        return out, made
    frame = base.copy()
    frame[rows, cols] = out
    return frame, made


def _box(mask: np.ndarray) -> tuple[slice, slice]:
    """The rows and columns of the bounding box of `mask` (H, W) bool, which holds at least one pixel."""
    ys, xs = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    return slice(int(ys[0]), int(ys[-1]) + 1), slice(int(xs[0]), int(xs[-1]) + 1)
