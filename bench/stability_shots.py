"""The stability bench's shots (bench.stability): a synthetic stand-in, a lazy view of a source shot (any length,
size or per-channel transform), and the transforms that make the hostile and noisy cases."""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from x2video.channels import INTRINSIC
from x2video.shot import Shot, ShotInfo


# --------------------------------------------------------------------------------------------- shots
class SyntheticShot(Shot):
    """A small analytic stand-in when no path-traced data is given: a sliding checker of albedos, a tilted
    normal field, a window (normal 0) and a metal strip, irradiance from a moving light; rgb = albedo x
    irradiance (plus a glossy term on the metal), in normalised units (irradiance_scale 1)."""

    def __init__(self, num_frames: int = 8, size: tuple[int, int] = (56, 80)):
        h, w = size
        self.info = ShotInfo(num_frames=num_frames, height=h, width=w, channels=(*INTRINSIC, "rgb", "ids"), caption="a synthetic room",
                             object_captions={1: "a red wall", 2: "a blue floor", 3: "a metal strip"}, source="synthetic")

    def _read(self, name: str, t: int) -> np.ndarray:
        h, w = self.size
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        x = x + 1.5 * t
        ids = (1 + ((x // 12 + y // 12) % 2)).astype(np.int32)
        window = (x % 60 < 10) & (y < h * 0.3)
        metal = (y > h * 0.7) & (x % 40 < 15)
        ids[metal] = 3
        ids[window] = 0
        if name == "ids":
            return ids[..., None]
        if name == "albedo":
            a = np.where(ids[..., None] == 1, [0.7, 0.2, 0.15], np.where(ids[..., None] == 2, [0.15, 0.25, 0.6], [0.9, 0.9, 0.9]))
            return np.where(window[..., None], 0.0, a).astype(np.float32)
        if name == "normal":
            n = np.stack([np.sin(x / w), np.zeros_like(y), np.cos(x / w)], -1)
            return np.where(window[..., None], 0.0, n).astype(np.float32)
        if name == "roughness":
            return np.where(metal, 0.03, 0.6).astype(np.float32)[..., None]
        if name == "metallic":
            return metal.astype(np.float32)[..., None]
        irr = (0.6 + 0.5 * np.exp(-((x - w / 2 - 3 * t) ** 2 + (y - h / 3) ** 2) / (0.1 * w * w)))[..., None] * np.array([1.0, 0.95, 0.85])
        irr = np.where(window[..., None], 0.0, irr).astype(np.float32)
        if name == "irradiance":
            return irr
        if name == "rgb":
            rgb = self._read("albedo", t) * irr + metal[..., None] * 0.3 * irr
            return np.where(window[..., None], 1.5, rgb).astype(np.float32)
        raise KeyError(name)


class ViewShot(Shot):
    """A lazy view of a source shot: frame t is source frame `src_index(t)` (ping-pong through the source, so
    any length has continuous motion), resized to `size`, then passed through `transform(name, array, t)`.
    Nothing is held: each read goes to the source (whose loader keeps a small LRU cache)."""

    def __init__(self, src: Shot, num_frames: int | None = None, size: tuple[int, int] | None = None,
                 transform: Callable[[str, np.ndarray, int], np.ndarray] | None = None, start: int = 0):
        self.src, self.transform, self.start = src, transform, start
        h, w = size or src.size
        self.info = dataclasses.replace(src.info, num_frames=int(num_frames or src.num_frames - start), height=h, width=w, poses=None)

    def src_index(self, t: int) -> int:
        n = self.src.num_frames - self.start
        if n <= 1:
            return self.start
        k = t % (2 * (n - 1))
        return self.start + (k if k < n else 2 * (n - 1) - k)

    def _read(self, name: str, t: int) -> np.ndarray:
        a = resize_channel(name, self.src.channel(name, self.src_index(t)), self.size)
        if self.transform is not None:
            a = self.transform(name, a, t)
        return a


def resize_channel(name: str, a: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Channel `name`'s (H, W, C) array resized to `size` (h, w): ids nearest, others area-averaged down, bilinear up."""
    import cv2

    if a.shape[:2] == tuple(size):
        return a
    h, w = size
    if name == "ids":
        r = cv2.resize(a[..., 0].astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
    else:
        interp = cv2.INTER_AREA if h < a.shape[0] else cv2.INTER_LINEAR
        r = cv2.resize(np.ascontiguousarray(a, np.float32), (w, h), interpolation=interp)
    return (r if r.ndim == 3 else r[..., None]).astype(a.dtype)


# --------------------------------------------------------------------------------------------- case transforms
def _patch(shape: tuple[int, int]) -> tuple[slice, slice]:
    h, w = shape
    return slice(h // 4, max(h // 4 + 1, h // 2)), slice(w // 4, max(w // 4 + 1, w // 2))


HOSTILE: dict[str, Callable[[str, np.ndarray], np.ndarray]] = {}


def _hostile(name: str, channel: str, fn: Callable[[np.ndarray], np.ndarray]) -> None:
    HOSTILE[name] = lambda ch, a: fn(a.copy()) if ch == channel else a


def _set_patch(v: float) -> Callable[[np.ndarray], np.ndarray]:
    def f(a: np.ndarray) -> np.ndarray:
        a[_patch(a.shape[:2])] = v
        return a
    return f


_hostile("nan_irradiance", "irradiance", _set_patch(np.nan))
_hostile("posinf_irradiance", "irradiance", _set_patch(np.inf))
_hostile("neginf_irradiance", "irradiance", _set_patch(-np.inf))
_hostile("irradiance_1e6", "irradiance", _set_patch(1e6))
_hostile("nan_albedo", "albedo", _set_patch(np.nan))
_hostile("negative_roughness", "roughness", lambda a: a * 0 - 0.5)
_hostile("zero_normals", "normal", lambda a: a * 0)
_hostile("albedo_0", "albedo", lambda a: a * 0)
_hostile("albedo_1", "albedo", lambda a: a * 0 + 1)


def poisson_noise(spp: int) -> Callable[[str, np.ndarray, int], np.ndarray]:
    """Irradiance x k/spp per pixel, k ~ Poisson(spp) shared by R, G, B: an unbiased estimate with relative
    standard deviation 1/sqrt(spp) and (at low spp) many black pixels, as a path tracer's few samples give."""

    def f(name: str, a: np.ndarray, t: int) -> np.ndarray:
        if name != "irradiance":
            return a
        rng = np.random.default_rng([spp, t])
        k = rng.poisson(spp, a.shape[:2]).astype(np.float32) / spp
        return (a * k[..., None]).astype(np.float32)
    return f


def cycles_noise(src: Shot) -> Callable[[str, np.ndarray, int], np.ndarray] | None:
    """The irradiance as Cycles sampled it (NoisyDiffDir + NoisyDiffInd, exposure-normalised like the
    denoised one), for a source shot from Cycles EXRs with those layers; None otherwise."""
    from x2video.train.residual_stage import noisy_irradiance

    folder = Path(str(src.info.source))
    files = sorted(folder.glob("*.exr")) if folder.is_dir() else []
    if len(files) != src.num_frames or noisy_irradiance(files[0]) is None:
        return None
    s = float(src.info.irradiance_scale)

    def f(name: str, a: np.ndarray, t: int) -> np.ndarray:
        if name != "irradiance":
            return a
        raw = noisy_irradiance(files[t])
        return (raw * s).astype(np.float32) if raw is not None and raw.shape == a.shape else a
    return f
