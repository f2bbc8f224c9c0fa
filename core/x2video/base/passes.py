"""The formula over the base: a frame rebuilt from its passes as a compositor would (issue 52 item 3), R of tier 0.

Cycles splits its Combined pass exactly:

    Combined = DiffCol x (DiffDir + DiffInd) + GlossCol x (GlossDir + GlossInd) + TransCol x (TransDir + TransInd)
               + Emit + Env (+ VolumeDir + VolumeInd)

A shot from Blender carries the terms as channels (`x2video.io.multilayer`): irradiance (DiffDir + DiffInd),
diffuse_color (DiffCol), glossy (the glossy, transmitted and volume light) and emission (Emit + Env); a
`FrameConditioning` holds them as its `passes`. `rebuild` sums them for a frame's (edited) conditioning:

- the diffuse term's factor is DiffCol, not the basecolor AOV (DiffCol is the base colour times what the BSDF keeps
  diffuse: 1 - metallic, 1 - transmission, 1 - a dielectric's specular share), and where an edit recolours, the new
  colour (`diffuse_color`). Over the base, the difference of two rebuilds is then the compositor's rebuild of an
  albedo edit (Combined - DiffCol x light + colour' x light), the floor tier 0 promises;
- the light operations scale irradiance and the light passes alike (`x2video.edits.ops`), so a light edit of every
  lamp scales every term: over the base as a ratio (`x2video.base.difference.over_base`), the base times the gain,
  exact wherever Cycles' light is linear in its lamps, emitters and world included.

- a metallic edit moves light between the two terms: Cycles' diffuse colour is black on a metal and its glossy colour
  (GlossCol, `glossy_color`) is the base colour there, about 0.04 on a dielectric (`DIELECTRIC_GLOSS`), while the
  light each term is divided by stays (on a test room's armchair made non-metal, DiffDir/DiffInd and
  GlossDir/GlossInd moved by under 2 %, GlossCol fell from 0.61 to 0.04). Where metallic changed, the diffuse factor
  becomes albedo x (1 - metallic) and the glossy term glossy x GlossCol' / GlossCol with GlossCol' =
  0.04 x (1 - metallic) + albedo x metallic: the compositor's rebuild of the change, which needs the glossy colour
  pass (without it the glossy term stays as it was);

Without the passes (a shot from elsewhere) `rebuild` is the formula, albedo x irradiance (`x2video.formula`), plus
whatever passes the shot does have (emission alone, say).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from x2video.formula import finite, formula

#: GlossCol of a dielectric: Fresnel reflectance at normal incidence of IOR 1.5 (Principled's default specular), what a
#: metal made non-metal reflects with (Cycles gave 0.037-0.047 on a test room's armchair made non-metal)
DIELECTRIC_GLOSS = 0.04

if TYPE_CHECKING:
    from x2video.conditioning.frame import FrameConditioning


def diffuse_color(cond: FrameConditioning, original: FrameConditioning) -> np.ndarray | None:
    """(H, W, 3) the factor of `cond`'s diffuse light: the shot's DiffCol where `cond`'s albedo is `original`'s (the
    shot's own), the (edited) albedo where an edit changed it or made a metal non-metal (Cycles' DiffCol is black on
    metals); the clipped albedo everywhere where the shot has no DiffCol. None without albedo.

    Over the base, the change an albedo edit makes is then colour' x light - DiffCol x light: the compositor's
    rebuild, the floor, exactly. The physically nearer factor, albedo' x DiffCol / albedo (what the BSDF keeps
    diffuse: about 0.95 of a dielectric's base colour in Blender 4, 0 on metals), scored below it on the tiny Cycles
    room of tests/test_edits_bench.py (28.8 dB inside against 29.3): an object made brighter also lights itself
    more (its own indirect light, which neither render of the change holds), and the full colour makes up for part of
    that; on metal parts (handles) it also drops the change of their tinted reflection, which the diffuse light
    stands for in the rebuild."""
    al = cond.channels.get("albedo")
    if al is None:
        return None
    al = np.clip(finite(al), 0, 1)
    dc, al0 = cond.passes.get("diffuse_color"), original.channels.get("albedo")
    if dc is None or al0 is None:
        return al
    own = al == np.clip(finite(al0), 0, 1)
    moved = metal_changed(cond, original)
    if moved is None:
        return np.where(own, np.clip(finite(dc), 0, 1), al).astype(np.float32)
    own &= ~moved
    new = al * (1 - np.clip(finite(np.asarray(cond.channels["metallic"])), 0, 1))  # what the BSDF keeps diffuse
    return np.where(own, np.clip(finite(dc), 0, 1), np.where(moved, new, al)).astype(np.float32)


def metal_changed(cond: FrameConditioning, original: FrameConditioning) -> np.ndarray | None:
    """(H, W, 1) bool: where an edit changed metallic; None where either frame has no metallic."""
    mo, me = original.channels.get("metallic"), cond.channels.get("metallic")
    if mo is None or me is None:
        return None
    return np.asarray(mo) != np.asarray(me)


def glossy_term(cond: FrameConditioning, original: FrameConditioning) -> np.ndarray | None:
    """(H, W, 3) the glossy term of `cond`: its glossy pass, times GlossCol' / GlossCol where an edit changed metallic
    and the frame has the glossy colour pass (see the module docstring); None without a glossy pass."""
    g = cond.passes.get("glossy")
    if g is None:
        return None
    g = np.maximum(finite(g), 0)
    gc, al, moved = cond.passes.get("glossy_color"), cond.channels.get("albedo"), metal_changed(cond, original)
    if gc is None or al is None or moved is None or not moved.any():
        return g
    m = np.clip(finite(np.asarray(cond.channels["metallic"])), 0, 1)
    gc = np.clip(finite(gc), 0, 1)
    new = DIELECTRIC_GLOSS * (1 - m) + np.clip(finite(al), 0, 1) * m
    ratio = np.where(gc > 1e-3, new / np.maximum(gc, 1e-3), 1.0)  # no glossy colour: no glossy light is known there
    return np.where(moved, g * ratio, g).astype(np.float32)


def rebuild(cond: FrameConditioning, original: FrameConditioning) -> np.ndarray:
    """(H, W, 3) float32 R of `cond` for the formula over the base (model exposure): `diffuse_color` x irradiance +
    glossy + emission, each pass where the frame has it; `original`: the frame unedited. Non-finite values count as 0,
    irradiance and the light passes are floored at 0."""
    al, ir = diffuse_color(cond, original), cond.channels.get("irradiance")
    out = formula({"albedo": al, "irradiance": ir}, cond.size) if al is not None and ir is not None else np.zeros((*cond.size, 3), np.float32)
    g, e = glossy_term(cond, original), cond.passes.get("emission")
    for p in (g, None if e is None else np.maximum(finite(e), 0)):
        if p is not None:
            out = out + p
    return out.astype(np.float32)

