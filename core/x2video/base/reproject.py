"""Reprojection by depth and camera: one frame's image seen from another frame, on the same surface only.

The carrier of the classical fill (`base.fill`): a keyframe's shading onto a frame between, and a frame's neighbours'
albedo onto it (`base.fill.stable_albedo`). `FrameMemo` keeps what reprojection reads of a frame (its camera, depth,
world normals, albedo) for the frames around the one being filled, so that filling a shot in order reads each frame
once instead of once per frame that reaches it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable

import numpy as np

from x2video.base.camera import View, project, unproject, world_normals
from x2video.shot import Shot

if TYPE_CHECKING:
    from x2video.base.fill import FillConfig


@dataclass(frozen=True)
class Geometry:
    """What reprojection needs of one frame: its camera, depth (H, W) and world normals (H, W, 3) (None without)."""

    view: View
    depth: np.ndarray
    normals: np.ndarray | None

    @classmethod
    def of(cls, shot: Shot, t: int) -> Geometry:
        if shot.info.poses is None:
            raise ValueError(f"shot {shot.info.source!r}: frame {t} has no camera pose to reproject by")
        view = View.of(shot.info.poses[t], shot.size)
        normals = world_normals(view, shot.channel("normal", t)) if shot.has("normal") else None
        return cls(view, shot.channel("depth", t)[..., 0], normals)


class FrameMemo:
    """Per-frame arrays of one shot (`Geometry`, channels) kept until `keep` says a frame is no longer needed."""

    def __init__(self, shot: Shot) -> None:
        self.shot = shot
        self._geometry: dict[int, Geometry] = {}
        self._channels: dict[tuple[str, int], np.ndarray] = {}

    def geometry(self, t: int) -> Geometry:
        if t not in self._geometry:
            self._geometry[t] = Geometry.of(self.shot, t)
        return self._geometry[t]

    def channel(self, name: str, t: int) -> np.ndarray:
        if (name, t) not in self._channels:
            self._channels[name, t] = self.shot.channel(name, t)
        return self._channels[name, t]

    def keep(self, frames: Iterable[int]) -> None:
        """Forget every frame not in `frames` (what a shot filled in order needs next: the frames in reach of it)."""
        wanted = set(frames)
        self._geometry = {t: g for t, g in self._geometry.items() if t in wanted}
        self._channels = {key: a for key, a in self._channels.items() if key[1] in wanted}

    def frames(self) -> set[int]:
        """The frames it holds anything of."""
        return set(self._geometry) | {t for _, t in self._channels}


def warp(gt: Geometry, gk: Geometry, image_k: np.ndarray, cfg: FillConfig) -> tuple[np.ndarray, np.ndarray]:
    """Frame k's `image_k` (H, W, C) seen from frame t: ((H, W, C) image, (H, W) validity), by their `Geometry`.

    Bilinear over the four pixels of k around each reprojected position, each weighed by whether it is the same
    surface (depth within `cfg.depth_tolerance`, normal within `cfg.normal_cos`): an interpolation never mixes a
    foreground object's shading into the wall behind it, which is where most of a plain bilinear warp's error lay
    (measured on the validation clip)."""
    h, w = gt.depth.shape
    x, y, d = project(gk.view, unproject(gt.view, gt.depth))
    normals = gt.normals is not None and gk.normals is not None
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    # frame k's arrays gathered by flat index (`take`), the normals' dot product written out: the same arithmetic in
    # the same order as 2-D fancy indexing and np.sum over the last axis, bit for bit, at about half the time
    c = image_k.shape[-1]
    img = np.ascontiguousarray(image_k, np.float32).reshape(-1, c)
    depth_k = np.ascontiguousarray(gk.depth).reshape(-1)
    normals_k = np.ascontiguousarray(gk.normals).reshape(-1, 3) if normals else None
    acc = np.zeros((h, w, c), np.float32)
    wsum = np.zeros((h, w), np.float32)
    inside = (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5) & (d > 0)
    tol = cfg.depth_tolerance * np.maximum(d, 1e-6)
    cols = [np.clip(x0 + dx, 0, w - 1).astype(np.int32) for dx in (0, 1)]
    rows = [np.clip(y0 + dy, 0, h - 1).astype(np.int32) * w for dy in (0, 1)]
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        idx = rows[dy] + cols[dx]
        wb = (fx if dx else 1 - fx) * (fy if dy else 1 - fy)
        ok = inside & (np.abs(depth_k.take(idx) - d) <= tol)
        if normals:
            n, nt = normals_k.take(idx, axis=0), gt.normals
            ok &= (n[..., 0] * nt[..., 0] + n[..., 1] * nt[..., 1] + n[..., 2] * nt[..., 2]) >= cfg.normal_cos
        wt = np.where(ok, np.maximum(wb, 1e-4), 0).astype(np.float32)
        acc += img.take(idx, axis=0) * wt[..., None]
        wsum += wt
    valid = wsum > 0
    return np.where(valid[..., None], acc / np.maximum(wsum, 1e-12)[..., None], 0).astype(np.float32), valid
