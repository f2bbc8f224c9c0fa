"""The editor's view of `x2video.edits`: index-addressed masks and a flat parameter dict per edit target,
mapped onto the foundation's `Edits` (masks by name, a list of ops). No Qt here."""
from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from x2video.channels import linear_to_srgb, srgb_to_linear
from x2video.conditioning import FrameConditioning
from x2video.edits import (
    AlbedoHSV,
    AlbedoSet,
    AlbedoTint,
    Edits,
    Exposure,
    LightTint,
    Mask,
    MaskOut,
    Op,
    Project,
    Reference,
    ScalarOp,
    apply_edits,
    propagate_mask,
    resolve_reference,
)
from x2video.edits import load_project as _load_project
from x2video.edits import save_project as _save_project
from x2video.edits.project import PROJECT_FORMAT, masks_dir
from x2video.shot import Shot

PROJECT_SUFFIX = ".x2v.json"

# -- shots and projects ----------------------------------------------------------------------


def load_shot(path: str | Path) -> Shot:
    from x2video.io import load_shot as _load

    return _load(path)


def looks_like_shot(d: Path) -> bool:
    return (Path(d) / "shot.json").is_file()


def is_project_file(p: Path) -> bool:
    p = Path(p)
    if not (p.is_file() and p.suffix == ".json" and p.name != "shot.json"):
        return False
    try:
        with open(p, encoding="utf-8") as f:
            head = json.load(f)
    except (OSError, ValueError):
        return False
    return isinstance(head, dict) and head.get("format") == PROJECT_FORMAT


def new_edits(shot: Shot | None = None) -> Edits:
    e = Edits()
    if shot is not None and shot.info.caption:
        e.global_prompt = shot.info.caption
    return e


def save_project(path: Path, shot_path: str | None, edits: Edits) -> None:
    if not shot_path:
        raise ValueError("the project has no shot file to refer to")
    _save_project(path, Project(shot=str(Path(shot_path).resolve()), edits=edits))


def load_project(path: Path) -> tuple[str, Edits]:
    p = _load_project(path)
    return p.shot, p.edits


def remove_project(path: Path) -> None:
    """Delete a project file and its mask folder (autosave side files)."""
    Path(path).unlink(missing_ok=True)
    d = masks_dir(path)
    if d.is_dir():
        shutil.rmtree(d, ignore_errors=True)


def apply(shot: Shot, edits: Edits, t: int) -> FrameConditioning:
    return apply_edits(shot, edits, t)


# -- masks -----------------------------------------------------------------------------------


def names(e: Edits) -> list[str]:
    return list(e.masks)


def num_masks(e: Edits | None) -> int:
    return 0 if e is None else len(e.masks)


def mask_name(e: Edits, i: int) -> str:
    return names(e)[i]


def mask_colour(e: Edits, i: int) -> tuple[int, int, int] | None:
    """Mask colours are a display choice, not part of the Edits: the Document keeps overrides."""
    return None


def mask_prompt(e: Edits, i: int) -> str:
    return e.local_prompts.get(mask_name(e, i), "")


def set_mask_prompt(e: Edits, i: int, text: str) -> None:
    name = mask_name(e, i)
    if text.strip():
        e.local_prompts[name] = text
    else:
        e.local_prompts.pop(name, None)


def mask_out(e: Edits, i: int) -> bool:
    name = mask_name(e, i)
    return any(isinstance(op, MaskOut) and op.mask == name for op in e.ops)


def set_mask_out(e: Edits, i: int, on: bool) -> None:
    name = mask_name(e, i)
    e.ops = [op for op in e.ops if not (isinstance(op, MaskOut) and op.mask == name)]
    if on:
        e.ops.append(MaskOut(mask=name))


def add_mask(e: Edits, name: str, colour: Any = None) -> int:
    base, k = name, 2
    while name in e.masks:
        name = f"{base} ({k})"
        k += 1
    e.masks[name] = Mask()
    return len(e.masks) - 1


def remove_mask(e: Edits, i: int) -> None:
    e.remove_mask(mask_name(e, i))


def set_mask_name(e: Edits, i: int, new: str) -> None:
    new = new.strip()
    if new and new != mask_name(e, i):
        e.rename_mask(mask_name(e, i), new)


def set_mask_colour(e: Edits, i: int, colour: Any) -> None:
    raise ValueError("mask colours live in the Document, not in the Edits")


def get_mask(e: Edits, i: int, t: int, size: tuple[int, int]) -> np.ndarray:
    """The painted array of frame t (zeros when unpainted): what brush and eraser modify."""
    a = e.masks[mask_name(e, i)].frames.get(t)
    return np.zeros(size, np.float32) if a is None else a.copy()


def set_mask(e: Edits, i: int, t: int, m: np.ndarray) -> None:
    mask = e.masks[mask_name(e, i)]
    if np.any(m):
        mask.paint(t, m)
    else:
        mask.erase(t)


def mask_at(shot: Shot, e: Edits, i: int, t: int) -> np.ndarray:
    """What the mask covers on frame t (painted, held, and object ids)."""
    return e.masks[mask_name(e, i)].at(shot, t)


def mask_frames(e: Edits, i: int) -> list[int]:
    return e.masks[mask_name(e, i)].painted_frames()


def mask_ids(e: Edits, i: int) -> list[int]:
    return list(e.masks[mask_name(e, i)].ids)


def add_mask_id(e: Edits, i: int, oid: int) -> None:
    m = e.masks[mask_name(e, i)]
    if oid not in m.ids:
        m.ids = [*m.ids, int(oid)]


def propagate(shot: Shot, e: Edits, i: int, t: int) -> None:
    """Carry the mask painted on frame t to every frame (the foundation's DIS-flow propagation)."""
    m = e.masks[mask_name(e, i)]
    src = m.frames.get(t)
    if src is None:
        raise ValueError(f"mask {mask_name(e, i)!r} is not painted on frame {t}")
    paint_frames(e, mask_name(e, i), propagate_mask(shot, src, t))


def paint_frames(e: Edits, name: str, frames: dict[int, np.ndarray]) -> None:
    """Paint mask `name` on each frame of `frames` (what a propagation computed)."""
    m = e.masks[name]
    for f, a in frames.items():
        m.paint(f, a)


# -- parametric edits: a flat dict per target (None = whole frame, else mask index) -------------

_PARAM_OPS = (AlbedoSet, AlbedoTint, AlbedoHSV, ScalarOp, Exposure, LightTint)


def _target_name(e: Edits, target: int | None) -> str | None:
    return None if target is None else mask_name(e, target)


def _lin_to_srgb3(c) -> tuple[float, float, float]:
    return tuple(float(x) for x in linear_to_srgb(np.asarray(c, np.float32)))  # type: ignore[return-value]


def _srgb_to_lin3(c) -> tuple[float, float, float]:
    return tuple(float(x) for x in srgb_to_linear(np.asarray(c, np.float32)))  # type: ignore[return-value]


def get_params(e: Edits, target: int | None) -> dict[str, Any]:
    """The panel's parameters for a target, read from its ops (colours shown sRGB-encoded)."""
    from x2video_app.edit_panel import DEFAULT_PARAMS

    p = dict(DEFAULT_PARAMS)
    name = _target_name(e, target)
    for op in e.ops:
        if op.mask != name or not isinstance(op, _PARAM_OPS):
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


def _ops_from_params(p: dict[str, Any], name: str | None) -> list[Op]:
    """Ops for non-neutral parameters, in a fixed order (set, tint, HSV, roughness, metallic, light)."""
    ops: list[Op] = []
    if p["albedo_colour"] is not None:
        ops.append(AlbedoSet(mask=name, color=_srgb_to_lin3(p["albedo_colour"])))
    if tuple(p["albedo_tint"]) != (1.0, 1.0, 1.0):
        ops.append(AlbedoTint(mask=name, color=_srgb_to_lin3(p["albedo_tint"])))
    if (p["hue"], p["saturation"], p["value"]) != (0.0, 1.0, 1.0):
        ops.append(AlbedoHSV(mask=name, hue=float(p["hue"]), saturation=float(p["saturation"]), value=float(p["value"])))
    for ch in ("roughness", "metallic"):
        if p[f"{ch}_mode"] != "none":
            ops.append(ScalarOp(mask=name, target_channel=ch, mode=p[f"{ch}_mode"], value=float(p[ch])))
    if p["exposure"] != 0.0:
        ops.append(Exposure(mask=name, stops=float(p["exposure"])))
    if tuple(p["irradiance_tint"]) != (1.0, 1.0, 1.0):
        ops.append(LightTint(mask=name, color=_srgb_to_lin3(p["irradiance_tint"])))
    return ops


def _replace_target_ops(e: Edits, target: int | None, p: dict[str, Any]) -> None:
    name = _target_name(e, target)
    mine = [k for k, op in enumerate(e.ops) if op.mask == name and isinstance(op, _PARAM_OPS)]
    at = mine[0] if mine else len(e.ops)
    rest = [op for k, op in enumerate(e.ops) if k not in set(mine)]
    at = min(at, len(rest))
    e.ops = rest[:at] + _ops_from_params(p, name) + rest[at:]


def set_param(e: Edits, target: int | None, key: str, value: Any) -> None:
    p = get_params(e, target)
    if key not in p:
        raise KeyError(f"unknown edit parameter {key!r}")
    p[key] = tuple(value) if isinstance(value, (list, tuple)) else value
    if key.endswith("_mode") and value == "none":
        p[key[: -len("_mode")]] = 0.0 if key.startswith("metallic") else 0.5
    _replace_target_ops(e, target, p)


def reset_params(e: Edits, target: int | None) -> None:
    from x2video_app.edit_panel import DEFAULT_PARAMS

    _replace_target_ops(e, target, dict(DEFAULT_PARAMS))


# -- prompts, channels, reference ---------------------------------------------------------------


def global_prompt(e: Edits) -> str:
    return e.global_prompt


def set_global_prompt(e: Edits, text: str) -> None:
    e.global_prompt = text


def dropped(e: Edits) -> set[str]:
    return set(e.dropped)


def set_dropped(e: Edits, name: str, on: bool) -> None:
    (e.dropped.add if on else e.dropped.discard)(name)


def reference_image(shot: Shot | None, e: Edits, base_dir: Path | None = None) -> np.ndarray | None:
    """Linear RGB (H, W, 3) of the reference at the shot's size, or None (none set, or unreadable)."""
    if shot is None or e.reference is None:
        return None
    try:
        r = resolve_reference(shot, e, base_dir)
    except (OSError, ValueError):
        return None
    return None if r is None else r[1]


def reference_text(e: Edits) -> str:
    r = e.reference
    if r is None:
        return "No reference: the model follows the channels and prompts only."
    if r.path is not None:
        return f"Image {Path(r.path).name} (placed at frame {r.position})"
    return f"Shot frame {r.frame} (rgb channel)"


def read_image(path: str | Path) -> np.ndarray:
    """Check an image file is readable as a reference (raises naming the file)."""
    from x2video.io.image import read_image as _read

    return _read(path).all()


def set_reference_image(e: Edits, path: str | Path) -> None:
    e.reference = Reference(path=str(path))


def clear_reference(e: Edits) -> None:
    e.reference = None
