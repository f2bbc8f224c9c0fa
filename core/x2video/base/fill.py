"""The classical fill (tier 0 of the keyframe fill): frames between path-traced keyframes from their G-buffers.

Every pixel of a frame between is reprojected into its two nearest keyframes, by depth and camera where the shot
has them (`base.camera`), else by optical flow on the G-buffers (`base.flow`). A keyframe's pixel is rejected where
its depth or normal disagrees with the frame's own (another surface occludes it there, or the pixel left the
view). What it carries is the keyframe's demodulated shading, (rgb - emission) / albedo, so the frame's own albedo
and emission (at full resolution, with their own texture) modulate it back; the albedo that demodulates and
modulates is each frame's averaged with its neighbours' reprojected onto it (`stable_albedo`: a Cycles albedo pass
is a few-sample estimate that is noisy differently on every frame, which the denoised keyframes are not); the two keyframes blend by their
distance in time and their validity. A pixel that no keyframe sees (a surface uncovered between them) takes the
frame's own irradiance where the shot has it (the diffuse light, in the rgb's units), else the shading spread in
from the pixels around it (normalised convolution): `FillResult.holes` says how many pixels that was.

`BaseFrames` is a render's base frame by frame in the model's exposure: the shot's rgb where a frame carries it, else
its fill, and the shading under either (`irradiance`, for `base.shading`).

`fill_inputs` gives what the fill of a frame is made of as arrays (the warped keyframes, their validity, the time
weights, the blended shading); the learned fill (`base.learned`, tier 1) corrects that shading with a network.

Everything here is in the units of the shot's rgb channel (file units: a Blender shot's Combined as Cycles wrote
it), not the renderer's exposure.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from x2video.base.reproject import FrameMemo, warp
from x2video.io.cache import LRU
from x2video.shot import Shot

if TYPE_CHECKING:
    from x2video.base.learned import LearnedFill


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
    #: frames either side whose albedo, reprojected by depth and camera, is averaged into the albedo that demodulates
    #: and modulates the shading (`stable_albedo`); 0: each frame's own albedo pass as it is
    albedo_frames: int = 2


@dataclass
class FillResult:
    """A filled frame: (H, W, 3) linear rgb in the shot's rgb units, and what it was made of."""

    rgb: np.ndarray
    #: fraction of pixels that no keyframe saw (filled from irradiance or spread in from around)
    holes: float
    #: how pixels were carried: "depth" (reprojection by depth and camera) or "flow" (optical flow on G-buffers)
    method: str
    #: (H, W, 3) the demodulated shading it modulated by the frame's albedo (rgb = shading x albedo + emission), in
    #: rgb's units; None on a keyframe (its rgb is its own)
    shading: np.ndarray | None = None


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


def stable_albedo(shot: Shot, t: int, cfg: FillConfig, memo: FrameMemo | None = None) -> np.ndarray:
    """Frame t's albedo (H, W, 3), averaged with the albedo of the `cfg.albedo_frames` frames either side where they
    see the same surface, reprojected onto t by depth and camera (`reproject.warp`); t's own where it cannot reproject.

    Cycles estimates the albedo pass from the pixel's few samples, so fine texture comes out as noise drawn anew on
    every frame, while the denoised rgb (keyframes and truth alike) is smooth there: modulating by that noise made
    the frames between flicker more than the truth (warping error 1.3x on a wall of fine texture), and averaging it
    over frames keeps what is the same surface on every frame and drops what is not."""
    memo = memo if memo is not None and memo.shot is shot else FrameMemo(shot)
    own = memo.channel("albedo", t).astype(np.float32)
    if cfg.albedo_frames <= 0 or not can_reproject(shot):
        return own
    acc, weight = own.copy(), np.ones(shot.size, np.float32)
    for j in range(max(0, t - cfg.albedo_frames), min(shot.num_frames, t + cfg.albedo_frames + 1)):
        if j != t:
            a, valid = warp(memo.geometry(t), memo.geometry(j), memo.channel("albedo", j).astype(np.float32), cfg)
            acc += a * valid[..., None]
            weight += valid
    return acc / weight[..., None]


def _albedo(shot: Shot, t: int, cfg: FillConfig, memo: FrameMemo | None = None) -> np.ndarray:
    """The albedo that (de)modulates frame t's shading: `stable_albedo`, floored at `cfg.albedo_floor`; 1 without albedo."""
    if not shot.has("albedo"):
        return np.ones((*shot.size, 3), np.float32)
    return np.maximum(stable_albedo(shot, t, cfg, memo), cfg.albedo_floor)


def _emission(shot: Shot, t: int) -> np.ndarray:
    return shot.channel("emission", t) if shot.has("emission") else np.zeros((*shot.size, 3), np.float32)


def demodulated(shot: Shot, k: int, cfg: FillConfig, memo: FrameMemo | None = None) -> np.ndarray:
    """Keyframe k's shading (rgb - emission) / albedo, (H, W, 3)."""
    return ((shot.channel("rgb", k) - _emission(shot, k)) / _albedo(shot, k, cfg, memo)).astype(np.float32)


def can_reproject(shot: Shot) -> bool:
    """The shot has what reprojection by depth and camera needs: depth, normals and a pose with a field of view."""
    poses = shot.info.poses
    return shot.has("depth") and poses is not None and all(p.fov_y_deg is not None for p in poses)


def warp_by_depth(shot: Shot, t: int, k: int, shading_k: np.ndarray, cfg: FillConfig,
                  memo: FrameMemo | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Keyframe k's `shading_k` seen from frame t through depth and camera: ((H, W, 3) shading, (H, W) validity),
    the same surface only (`reproject.warp`)."""
    memo = memo if memo is not None and memo.shot is shot else FrameMemo(shot)
    return warp(memo.geometry(t), memo.geometry(k), shading_k, cfg)


@dataclass
class FillInputs:
    """What the classical fill of a frame between is made of, as arrays (the learned fill's input, `base.learned`).

    `near` holds the one or two keyframes it is carried from (earlier first); `warped[i]` is keyframe near[i]'s
    demodulated shading seen from the frame, (H, W, 3), `valid[i]` where that is the same surface, (H, W) bool, and
    `time_weight[i]` its weight by distance in time (the two sum to 1). `shading` is the blend with the holes filled,
    the classical fill's demodulated shading (H, W, 3); `holes` (H, W) bool the pixels no keyframe saw."""

    near: tuple[int, ...]
    warped: list[np.ndarray]
    valid: list[np.ndarray]
    time_weight: list[float]
    shading: np.ndarray
    holes: np.ndarray
    method: str


def fill_inputs(shot: Shot, t: int, cfg: FillConfig = FillConfig(), keyframes: Sequence[int] | None = None,
                shading: dict | None = None) -> FillInputs:
    """The warped keyframes, their validity and the classical fill's shading of frame t, which is no keyframe
    (`shading`: the cache `fill_frame` keeps across calls)."""
    keys = tuple(shot.keyframes if keyframes is None else keyframes)
    near = nearest_keyframes(t, keys)
    if near == (t,):
        raise ValueError(f"shot {shot.info.source!r}: frame {t} is a keyframe; there is nothing to fill")
    cache = shading if shading is not None else {}
    memo = frame_memo(cache, shot)
    use_depth = can_reproject(shot)
    acc = np.zeros((*shot.size, 3), np.float32)
    weight = np.zeros(shot.size, np.float32)
    warped, valids, times = [], [], []
    for k in near:
        if k not in cache:
            cache[k] = demodulated(shot, k, cfg, memo)
        if use_depth:
            s, valid = warp_by_depth(shot, t, k, cache[k], cfg, memo)
        else:
            from x2video.base.flow import warp_by_flow

            s, valid = warp_by_flow(shot, t, k, cache[k], cfg)
        w_time = 1.0 if len(near) == 1 else 1.0 - abs(t - k) / abs(near[1] - near[0])
        w = valid.astype(np.float32) * max(w_time, 1e-3)
        acc += s * w[..., None]
        weight += w
        warped.append(s)
        valids.append(valid)
        times.append(float(w_time))
    seen = weight > 0
    out = np.where(seen[..., None], acc / np.maximum(weight, 1e-12)[..., None], 0).astype(np.float32)
    holes = ~seen
    if holes.any():
        out = _fill_holes(shot, t, out, holes)
    return FillInputs(near, warped, valids, times, out, holes, "depth" if use_depth else "flow")


def modulation(shot: Shot, t: int, cfg: FillConfig = FillConfig(), memo: FrameMemo | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Frame t's (albedo as the fill (de)modulates with it, `_albedo`, emission), each (H, W, 3): rgb = shading x albedo
    + emission."""
    return _albedo(shot, t, cfg, memo), _emission(shot, t)


def modulated(shot: Shot, t: int, shading: np.ndarray, cfg: FillConfig = FillConfig(), memo: FrameMemo | None = None) -> np.ndarray:
    """(H, W, 3) rgb of frame t from its demodulated `shading`: shading x albedo + emission, >= 0."""
    albedo, emission = modulation(shot, t, cfg, memo)
    return np.maximum(shading * albedo + emission, 0).astype(np.float32)


def fill_frame(shot: Shot, t: int, cfg: FillConfig = FillConfig(), keyframes: Sequence[int] | None = None,
               shading: dict | None = None, learned: LearnedFill | None = None) -> FillResult:
    """Frame t of `shot` filled from its nearest keyframes (default `shot.keyframes`); a keyframe returns its rgb.

    `shading` is a cache kept across calls on one shot (start it as {}): keyframes' demodulated shading (frame ->
    array), and under "frames" a `FrameMemo` of the frames in reach of the one filled last (its neighbours for
    `stable_albedo`, its keyframes), so that a shot filled in order reads each frame once. `learned` (tier 1 of the fill,
    `base.learned.load_learned_fill`): its network corrects the classical fill's shading; without it the fill is
    the classical one (tier 0)."""
    keys = tuple(shot.keyframes if keyframes is None else keyframes)
    if nearest_keyframes(t, keys) == (t,):
        return FillResult(shot.channel("rgb", t), 0.0, "keyframe")
    cache = shading if shading is not None else {}
    inputs = fill_inputs(shot, t, cfg, keys, cache)
    out = inputs.shading if learned is None else learned.shading(shot, t, inputs, cfg)
    memo = frame_memo(cache, shot)
    rgb = modulated(shot, t, out, cfg, memo)
    r = cfg.albedo_frames
    memo.keep([*range(t - r, t + r + 2), *inputs.near])  # what frame t + 1 reaches
    return FillResult(rgb, float(inputs.holes.mean()), inputs.method, out)


def frame_memo(cache: dict, shot: Shot) -> FrameMemo:
    """The `FrameMemo` of `shot` kept in a `fill_frame` cache under "frames" (a new one for another shot)."""
    memo = cache.get("frames")
    if not isinstance(memo, FrameMemo) or memo.shot is not shot:
        memo = cache["frames"] = FrameMemo(shot)
    return memo


def _fill_holes(shot: Shot, t: int, shading: np.ndarray, holes: np.ndarray) -> np.ndarray:
    """Shading where no keyframe saw the surface: the frame's irradiance in the rgb's units where it carries it, else
    spread in from the shading around (`base.difference.spread_into`)."""
    if shot.has("irradiance", t):
        irr = shot.channel("irradiance", t) / max(shot.info.irradiance_scale, 1e-12)
        return np.where(holes[..., None], irr, shading).astype(np.float32)
    from x2video.base.difference import spread_into

    return spread_into(shading, holes)


class BaseFrames:
    """Frame t's base in the model's exposure (float64): the shot's rgb, or the fill between its keyframes."""

    def __init__(self, shot: Shot, cfg: FillConfig = FillConfig()) -> None:
        self.shot, self.cfg = shot, cfg
        self.scale = float(shot.info.irradiance_scale)
        self._shading: dict = {}  # fill_frame's cache across frames (keyframes' shading, the frames in reach)
        self._fills = LRU(4)  # the last frames filled: a frame's base and its irradiance (`irradiance`) fill it once
        #: frame -> fraction of its pixels that no keyframe saw (filled frames only)
        self.holes: dict[int, float] = {}

    def _fill(self, t: int) -> FillResult:
        res = self._fills.get_or(t, lambda: fill_frame(self.shot, t, self.cfg, shading=self._shading))
        self.holes[t] = res.holes
        return res

    def input_units(self, t: int) -> np.ndarray:
        """(H, W, 3) float32 base of frame t in the shot's rgb units."""
        if self.shot.has_rgb(t):
            return self.shot.channel("rgb", t)
        return self._fill(t).rgb

    def __call__(self, t: int) -> np.ndarray:
        return self.input_units(t).astype(np.float64) * self.scale

    def irradiance(self, t: int) -> np.ndarray:
        """(H, W, 3) float32 the base's shading of frame t as irradiance (times the shot's irradiance_scale): the fill's
        demodulated shading between keyframes, a keyframe's own (rgb - emission) / albedo (`base.shading`)."""
        if self.shot.has_rgb(t):
            if t not in self._shading:
                self._shading[t] = demodulated(self.shot, t, self.cfg)
            shading = self._shading[t]
        else:
            shading = self._fill(t).shading
        return (shading * np.float32(self.scale)).astype(np.float32)
