"""The classical fill (tier 0 of the keyframe fill): frames between path-traced keyframes from their G-buffers.

Every pixel of a frame between is reprojected into its two nearest keyframes, by depth and camera where the shot
has them (`base.camera`), else by optical flow on the G-buffers (`base.flow`). A keyframe's pixel is rejected where
its depth or normal disagrees with the frame's own (another surface occludes it there, or the pixel left the
view). What it carries is the keyframe's demodulated shading, (rgb - emission) / albedo, so the frame's own albedo
and emission (at full resolution, with their own texture) modulate it back; the two keyframes blend by their
distance in time and their validity. A pixel that no keyframe sees (a surface uncovered between them) takes the
frame's own irradiance where the shot has it (the diffuse light, in the rgb's units), else the shading spread in
from the pixels around it (normalised convolution): `FillResult.holes` says how many pixels that was.

Everything here is in the units of the shot's rgb channel (file units: a Blender shot's Combined as Cycles wrote
it), not the renderer's exposure.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from x2video.base.camera import View, project, unproject, world_normals
from x2video.shot import Shot


@dataclass(frozen=True)
class FillConfig:
    """The classical fill's thresholds (chosen on a validation clip: bench/keyframes.py)."""

    #: a keyframe's pixel is the same surface when its depth is within this fraction of the reprojected depth
    depth_tolerance: float = 0.02
    #: ... and its world normal within this cosine of the frame's own
    normal_cos: float = 0.9
    #: albedo below this is taken as this when (de)modulating (black surfaces keep their radiance, not 0 / 0)
    albedo_floor: float = 0.03
    #: flow (no depth or camera): forward-backward disagreement in pixels above which a pixel is rejected
    flow_consistency: float = 1.0


@dataclass
class FillResult:
    """A filled frame: (H, W, 3) linear rgb in the shot's rgb units, and what it was made of."""

    rgb: np.ndarray
    #: fraction of pixels that no keyframe saw (filled from irradiance or spread in from around)
    holes: float
    #: how pixels were carried: "depth" (reprojection by depth and camera) or "flow" (optical flow on G-buffers)
    method: str


def nearest_keyframes(t: int, keyframes: Sequence[int]) -> tuple[int, ...]:
    """The keyframes that bracket frame t (one when t is outside them or a keyframe itself)."""
    keys = sorted(keyframes)
    if not keys:
        raise ValueError("no keyframes: the shot carries no rgb to fill from")
    if t in keys:
        return (t,)
    before = [k for k in keys if k < t]
    after = [k for k in keys if k > t]
    return tuple(x for x in (before[-1] if before else None, after[0] if after else None) if x is not None)


def _albedo(shot: Shot, t: int, floor: float) -> np.ndarray:
    return np.maximum(shot.channel("albedo", t), floor) if shot.has("albedo") else np.ones((*shot.size, 3), np.float32)


def _emission(shot: Shot, t: int) -> np.ndarray:
    return shot.channel("emission", t) if shot.has("emission") else np.zeros((*shot.size, 3), np.float32)


def demodulated(shot: Shot, k: int, cfg: FillConfig) -> np.ndarray:
    """Keyframe k's shading (rgb - emission) / albedo, (H, W, 3)."""
    return ((shot.channel("rgb", k) - _emission(shot, k)) / _albedo(shot, k, cfg.albedo_floor)).astype(np.float32)


def can_reproject(shot: Shot) -> bool:
    """The shot has what reprojection by depth and camera needs: depth, normals and a pose with a field of view."""
    poses = shot.info.poses
    return shot.has("depth") and poses is not None and all(p.fov_y_deg is not None for p in poses)


def warp_by_depth(shot: Shot, t: int, k: int, shading_k: np.ndarray, cfg: FillConfig) -> tuple[np.ndarray, np.ndarray]:
    """Keyframe k's `shading_k` seen from frame t through depth and camera: ((H, W, 3) shading, (H, W) validity).

    Bilinear over the four keyframe pixels around each reprojected position, each weighed by whether it is the same
    surface (depth and normal agree): an interpolation never mixes a foreground object's shading into the wall
    behind it, which is where most of a plain bilinear warp's error lay (measured on the validation clip)."""
    assert shot.info.poses is not None
    vt, vk = View.of(shot.info.poses[t], shot.size), View.of(shot.info.poses[k], shot.size)
    h, w = shot.size
    x, y, d = project(vk, unproject(vt, shot.channel("depth", t)[..., 0]))
    depth_k = shot.channel("depth", k)[..., 0]
    normals = shot.has("normal")
    if normals:
        nt = world_normals(vt, shot.channel("normal", t))
        nk = world_normals(vk, shot.channel("normal", k))
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    acc = np.zeros((h, w, 3), np.float32)
    wsum = np.zeros((h, w), np.float32)
    inside = (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5) & (d > 0)
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        xi = np.clip(x0 + dx, 0, w - 1).astype(np.int32)
        yi = np.clip(y0 + dy, 0, h - 1).astype(np.int32)
        wb = (fx if dx else 1 - fx) * (fy if dy else 1 - fy)
        ok = inside & (np.abs(depth_k[yi, xi] - d) <= cfg.depth_tolerance * np.maximum(d, 1e-6))
        if normals:
            ok &= np.sum(nk[yi, xi] * nt, -1) >= cfg.normal_cos
        wt = np.where(ok, np.maximum(wb, 1e-4), 0).astype(np.float32)
        acc += shading_k[yi, xi] * wt[..., None]
        wsum += wt
    valid = wsum > 0
    return np.where(valid[..., None], acc / np.maximum(wsum, 1e-12)[..., None], 0).astype(np.float32), valid


def fill_frame(shot: Shot, t: int, cfg: FillConfig = FillConfig(), keyframes: Sequence[int] | None = None,
               shading: dict[int, np.ndarray] | None = None) -> FillResult:
    """Frame t of `shot` filled from its nearest keyframes (default `shot.keyframes`); a keyframe returns its rgb.

    `shading` caches keyframes' demodulated shading across calls (frame -> array)."""
    keys = tuple(shot.keyframes if keyframes is None else keyframes)
    near = nearest_keyframes(t, keys)
    if near == (t,):
        return FillResult(shot.channel("rgb", t), 0.0, "keyframe")
    cache = shading if shading is not None else {}
    use_depth = can_reproject(shot)
    acc = np.zeros((*shot.size, 3), np.float32)
    weight = np.zeros(shot.size, np.float32)
    for k in near:
        if k not in cache:
            cache[k] = demodulated(shot, k, cfg)
        if use_depth:
            s, valid = warp_by_depth(shot, t, k, cache[k], cfg)
        else:
            from x2video.base.flow import warp_by_flow

            s, valid = warp_by_flow(shot, t, k, cache[k], cfg)
        w_time = 1.0 if len(near) == 1 else 1.0 - abs(t - k) / abs(near[1] - near[0])
        w = valid.astype(np.float32) * max(w_time, 1e-3)
        acc += s * w[..., None]
        weight += w
    seen = weight > 0
    out = np.where(seen[..., None], acc / np.maximum(weight, 1e-12)[..., None], 0).astype(np.float32)
    holes = ~seen
    if holes.any():
        out = _fill_holes(shot, t, out, holes)
    rgb = out * _albedo(shot, t, cfg.albedo_floor) + _emission(shot, t)
    return FillResult(np.maximum(rgb, 0).astype(np.float32), float(holes.mean()), "depth" if use_depth else "flow")


def _fill_holes(shot: Shot, t: int, shading: np.ndarray, holes: np.ndarray) -> np.ndarray:
    """Shading where no keyframe saw the surface: the frame's irradiance in the rgb's units, else spread in from the
    shading around (`base.difference.spread_into`)."""
    if shot.has("irradiance"):
        irr = shot.channel("irradiance", t) / max(shot.info.irradiance_scale, 1e-12)
        return np.where(holes[..., None], irr, shading).astype(np.float32)
    from x2video.base.difference import spread_into

    return spread_into(shading, holes)
