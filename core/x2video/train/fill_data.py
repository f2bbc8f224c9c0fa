"""Training samples of the learned keyframe fill: a frame between two keyframes of a fully path-traced shot.

A sample takes a shot with rgb on every frame, picks N (the keyframe spacing) and a keyframe phase, keeps rgb on the
two keyframes around a frame t only (as a keyframe shot carries it), and makes what the fill of t is made of
(`base.fill.fill_inputs`, `base.learned.features`); t's own rgb is the target. With some probability the sample hides
the shot's irradiance (keyframe shots may have none) or its depth and cameras (the fill falls back to flow).

Shots are read once into a cache folder of one .npy per channel (`cache_shot`), memory-mapped when training
(`CachedShot`): a multi-layer EXR is decoded once, not once per sample.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from x2video.base.fill import FillConfig, can_reproject, fill_inputs, modulation
from x2video.base.learned import features
from x2video.io.atomic import write_json_atomic
from x2video.shot import CameraPose, Shot, ShotInfo

#: the channels a fill sample reads (rgb and albedo required, the others where the shot has them)
CHANNELS = ("rgb", "albedo", "normal", "roughness", "metallic", "emission", "depth", "irradiance")
#: the plane of the features that holds the camera-space normal's x (negated by a left-right flip)
NORMAL_X_PLANE = 18


def check_shot(shot: Shot, name: str) -> None:
    """ValueError naming the shot when the fill cannot train on it."""
    if not shot.has("rgb") or shot.info.rgb_frames is not None:
        raise ValueError(f"{name}: the learned fill trains on shots with rgb on every frame (this one has "
                         f"{'none' if not shot.has('rgb') else 'keyframes only'})")
    if not shot.has("albedo"):
        raise ValueError(f"{name}: has no albedo; the fill carries demodulated shading, (rgb - emission) / albedo")
    if shot.num_frames < 3:
        raise ValueError(f"{name}: {shot.num_frames} frames; a frame between two keyframes needs at least 3")


def cache_shot(shot_dir: Path, cache_dir: Path) -> Path:
    """Read the shot folder once into `cache_dir/<parent>_<name>/` (one .npy per channel, meta.json last)."""
    from x2video.io.load import load_shot

    out = cache_dir / f"{shot_dir.parent.name}_{shot_dir.name}"
    if (out / "meta.json").is_file():
        return out
    shot = load_shot(shot_dir)
    check_shot(shot, str(shot_dir))
    out.mkdir(parents=True, exist_ok=True)
    names = [c for c in CHANNELS if shot.has(c)]
    for c in names:
        arr = np.stack([shot.channel(c, t) for t in range(shot.num_frames)])  # (T, H, W, C)
        np.save(out / f"{c}.npy", arr.astype(np.float32 if c == "depth" else np.float16))
    poses = shot.info.poses
    write_json_atomic(out / "meta.json", {
        "source": str(shot_dir), "num_frames": shot.num_frames, "height": shot.size[0], "width": shot.size[1],
        "channels": names, "irradiance_scale": float(shot.info.irradiance_scale),
        "poses": None if poses is None else [{"cam_to_world": np.asarray(p.cam_to_world, float).tolist(), "fov_y_deg": p.fov_y_deg}
                                              for p in poses]})
    return out


class CachedShot(Shot):
    """A shot cached by `cache_shot`, its channels memory-mapped."""

    def __init__(self, folder: Path) -> None:
        meta = json.loads((folder / "meta.json").read_text())
        self._arrays = {c: np.load(folder / f"{c}.npy", mmap_mode="r") for c in meta["channels"]}
        poses = None if meta["poses"] is None else [CameraPose(np.asarray(p["cam_to_world"]), p["fov_y_deg"]) for p in meta["poses"]]
        self.info = ShotInfo(num_frames=meta["num_frames"], height=meta["height"], width=meta["width"],
                             channels=tuple(meta["channels"]), poses=poses, irradiance_scale=meta["irradiance_scale"],
                             source=meta["source"])

    def _read(self, name: str, t: int) -> np.ndarray:
        return np.asarray(self._arrays[name][t], np.float32)


class Seen(Shot):
    """`shot` as a sample shows it to the fill: rgb on `keys` only, without the `hidden` channels (and without
    cameras when depth is hidden)."""

    def __init__(self, shot: Shot, keys: Sequence[int], hidden: Sequence[str] = ()) -> None:
        self.base_shot = shot
        self.info = replace(shot.info, channels=tuple(c for c in shot.channels if c not in hidden), rgb_frames=tuple(sorted(keys)),
                            poses=None if "depth" in hidden else shot.info.poses)

    def _read(self, name: str, t: int) -> np.ndarray:
        return self.base_shot.channel(name, t)


@dataclass(frozen=True)
class Spec:
    """One sample: frame t of shot `shot` between keyframes k0 < t < k1, with `hidden` channels."""

    shot: int
    k0: int
    k1: int
    t: int
    hidden: tuple[str, ...] = ()


def draw(rng: np.random.Generator, shots: Sequence[Shot], every: Sequence[int], irradiance_dropout: float, flow_p: float) -> Spec:
    """A random sample: shot, N from `every` (those the shot is long enough for), keyframe phase and frame between."""
    i = int(rng.integers(len(shots)))
    shot = shots[i]
    n_frames = shot.num_frames
    ns = [n for n in every if 2 <= n <= n_frames - 1] or [n_frames - 1]
    n = int(ns[int(rng.integers(len(ns)))])
    k0 = int(rng.integers(n_frames - n))
    t = k0 + int(rng.integers(1, n))
    hidden = []
    if shot.has("irradiance") and rng.random() < irradiance_dropout:
        hidden.append("irradiance")
    if can_reproject(shot) and rng.random() < flow_p:
        hidden.append("depth")
    return Spec(i, k0, k0 + n, t, tuple(hidden))


@dataclass
class Sample:
    """What a training step needs of one frame between, (C, H, W) float16 planes: the network's input `x`, the
    classical fill's shading `shading`, the albedo (floored) and emission that modulate it, the truth `target` (the
    shot's rgb), and the frame's light `level` (`base.learned.light_level`)."""

    x: np.ndarray
    shading: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    target: np.ndarray
    level: float
    spec: Spec


def make_sample(shots: Sequence[Shot], spec: Spec, cfg: FillConfig = FillConfig()) -> Sample:
    shot = shots[spec.shot]
    seen = Seen(shot, (spec.k0, spec.k1), spec.hidden)
    inputs = fill_inputs(seen, spec.t, cfg)
    x, level = features(seen, spec.t, inputs)
    albedo, emission = modulation(seen, spec.t, cfg)

    def planes(v: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(np.asarray(v, np.float32).transpose(2, 0, 1)).astype(np.float16)

    return Sample(x.astype(np.float16), planes(inputs.shading), planes(albedo), planes(emission),
                  planes(shot.channel("rgb", spec.t)), level, spec)


def crops(samples: Sequence[Sample], rng: np.random.Generator, n: int, size: int) -> dict[str, np.ndarray]:
    """`n` random crops of `size` pixels a side (the frame's side where smaller) from random `samples`, each flipped
    left-right half the time: a batch of float32 planes (N, C, s, s) and the levels (N, 1, 1, 1)."""
    keys = ("x", "shading", "albedo", "emission", "target")
    out: dict[str, list] = {k: [] for k in (*keys, "level")}
    s_h = min(size, *(smp.x.shape[1] for smp in samples))
    s_w = min(size, *(smp.x.shape[2] for smp in samples))
    for _ in range(n):
        smp = samples[int(rng.integers(len(samples)))]
        h, w = smp.x.shape[1:]
        r, c = int(rng.integers(h - s_h + 1)), int(rng.integers(w - s_w + 1))
        flip = rng.random() < 0.5
        for k in keys:
            v = getattr(smp, k)[:, r:r + s_h, c:c + s_w].astype(np.float32)
            if flip:
                v = v[:, :, ::-1].copy()
                if k == "x":
                    v[NORMAL_X_PLANE] = -v[NORMAL_X_PLANE]
            out[k].append(v)
        out["level"].append(np.full((1, 1, 1), smp.level, np.float32))
    return {k: np.stack(v) for k, v in out.items()}
