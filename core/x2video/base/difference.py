"""Edits as differences over the base: Debevec's differential rendering, out = base + R(edited) - R(original).

R is a tier's render of a frame's channels; its systematic errors (light the five channels do not hold: sky, lamps,
mirrors, glass) appear in both renders and cancel, so the base keeps them. An edit reaches the pixels whose
channels it changed, plus a margin for the light it spills onto its surroundings (`reach`); every other pixel is
the base, bit for bit.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Literal

import cv2
import numpy as np

from x2video.channels import INTRINSIC
from x2video.conditioning.frame import FrameConditioning

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
    from x2video.base.passes import passes_changed

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
    return np.where(where[..., None], np.maximum(new, 0.0), base)


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
    metallic): where tier 1's difference is not used (`x2video.base.stage.edited_frame`). A sharper reflection shows
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
