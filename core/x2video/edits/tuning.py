"""Parametric tuning as one flat set of values per target (a mask, or the whole frame), mapped onto the ops.

This is the view a tuning panel edits: `NEUTRAL_TUNING` lists every value with its neutral setting (neutral =
no op). Colours are sRGB-encoded in [0, 1], as a colour picker shows them; the ops store them linear.
`tuning_of(ops, mask)` reads a target's values back from its ops; `ops_for(values, mask)` writes the ops for the
non-neutral ones. `Edits.tuning`, `Edits.set_tuning` and `Edits.reset_tuning` use them.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from x2video.channels import linear_to_srgb, srgb_to_linear
from x2video.edits.ops import AlbedoHSV, AlbedoSet, AlbedoTint, Exposure, LightTint, Op, ScalarOp

#: every tuning value with its neutral setting (colours sRGB in [0, 1])
NEUTRAL_TUNING: dict[str, Any] = {
    "albedo_colour": None,  # set colour, or None
    "albedo_tint": (1.0, 1.0, 1.0),  # multiply
    "hue": 0.0,  # degrees
    "saturation": 1.0,  # scale
    "value": 1.0,  # scale
    "roughness_mode": "none",  # none | set | offset | scale
    "roughness": 0.5,
    "metallic_mode": "none",
    "metallic": 0.0,
    "exposure": 0.0,  # stops
    "irradiance_tint": (1.0, 1.0, 1.0),
}

#: the ops a tuning stands for (a `MaskOut` is not one of them)
TUNING_OPS = (AlbedoSet, AlbedoTint, AlbedoHSV, ScalarOp, Exposure, LightTint)


def _lin_to_srgb3(c) -> tuple[float, float, float]:
    return tuple(float(x) for x in linear_to_srgb(np.asarray(c, np.float32)))  # type: ignore[return-value]


def _srgb_to_lin3(c) -> tuple[float, float, float]:
    return tuple(float(x) for x in srgb_to_linear(np.asarray(c, np.float32)))  # type: ignore[return-value]


def tuning_of(ops: list[Op], mask: str | None) -> dict[str, Any]:
    """The tuning values of target `mask` (None: the whole frame), read from its ops."""
    p = dict(NEUTRAL_TUNING)
    for op in ops:
        if op.mask != mask or not isinstance(op, TUNING_OPS):
            continue
        if isinstance(op, AlbedoSet):
            p["albedo_colour"] = _lin_to_srgb3(op.color)
        elif isinstance(op, AlbedoTint):
            p["albedo_tint"] = _lin_to_srgb3(op.color)
        elif isinstance(op, AlbedoHSV):
            p["hue"], p["saturation"], p["value"] = float(op.hue), float(op.saturation), float(op.value)
        elif isinstance(op, ScalarOp):
            p[f"{op.target_channel}_mode"], p[op.target_channel] = op.mode, float(op.value)
        elif isinstance(op, Exposure):
            p["exposure"] = float(op.stops)
        elif isinstance(op, LightTint):
            p["irradiance_tint"] = _lin_to_srgb3(op.color)
    return p


def ops_for(p: dict[str, Any], mask: str | None) -> list[Op]:
    """Ops for the non-neutral values of `p`, in a fixed order (set, tint, HSV, roughness, metallic, light)."""
    ops: list[Op] = []
    if p["albedo_colour"] is not None:
        ops.append(AlbedoSet(mask=mask, color=_srgb_to_lin3(p["albedo_colour"])))
    if tuple(p["albedo_tint"]) != (1.0, 1.0, 1.0):
        ops.append(AlbedoTint(mask=mask, color=_srgb_to_lin3(p["albedo_tint"])))
    if (p["hue"], p["saturation"], p["value"]) != (0.0, 1.0, 1.0):
        ops.append(AlbedoHSV(mask=mask, hue=float(p["hue"]), saturation=float(p["saturation"]), value=float(p["value"])))
    for ch in ("roughness", "metallic"):
        if p[f"{ch}_mode"] != "none":
            ops.append(ScalarOp(mask=mask, target_channel=ch, mode=p[f"{ch}_mode"], value=float(p[ch])))
    if p["exposure"] != 0.0:
        ops.append(Exposure(mask=mask, stops=float(p["exposure"])))
    if tuple(p["irradiance_tint"]) != (1.0, 1.0, 1.0):
        ops.append(LightTint(mask=mask, color=_srgb_to_lin3(p["irradiance_tint"])))
    return ops


def with_value(p: dict[str, Any], key: str, value: Any) -> dict[str, Any]:
    """`p` with `key` set to `value`; a mode set to "none" puts its value back to neutral."""
    if key not in p:
        raise KeyError(f"unknown tuning value {key!r} (one of {', '.join(NEUTRAL_TUNING)})")
    p = {**p, key: tuple(value) if isinstance(value, (list, tuple)) else value}
    if key.endswith("_mode") and value == "none":
        channel = key[: -len("_mode")]
        p[channel] = NEUTRAL_TUNING[channel]
    return p
