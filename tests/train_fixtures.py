"""Tiny in-memory rooms for the training smoke tests: `ArrayShot`s with every channel, object ids and captions."""
from __future__ import annotations

import numpy as np

from x2video.shot import ArrayShot


def tiny_room(seed: int, frames: int = 9, size: tuple[int, int] = (32, 24), objects: int = 3) -> ArrayShot:
    """A room of `frames` frames at size=(w, h): a few moving rectangles (objects 1..objects) on a background."""
    rng = np.random.default_rng(seed)
    w, h = size
    t = frames
    ids = np.zeros((t, h, w), np.int32)
    for k in range(1, objects + 1):
        y0, x0 = rng.integers(0, h // 2), rng.integers(0, w // 2)
        hh, ww = rng.integers(h // 4, h // 2), rng.integers(w // 4, w // 2)
        for i in range(t):
            dx = i % max(1, w // 4)
            ids[i, y0 : y0 + hh, x0 + dx : x0 + dx + ww] = k
    colours = rng.uniform(0.05, 0.9, (objects + 1, 3)).astype(np.float32)
    rough = rng.uniform(0.1, 1.0, objects + 1).astype(np.float32)
    metal = (rng.uniform(size=objects + 1) > 0.7).astype(np.float32)
    normals = rng.normal(size=(objects + 1, 3)).astype(np.float32)
    normals[:, 2] = np.abs(normals[:, 2]) + 0.5
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    albedo = colours[ids]
    yy, xx = np.mgrid[0:h, 0:w]
    light = (0.5 + 1.5 * np.exp(-((xx - w * rng.uniform()) ** 2 + (yy - h * rng.uniform()) ** 2) / (0.3 * w * h)))
    irradiance = np.repeat(light[None, ..., None], t, 0).astype(np.float32) * np.array([1.0, 0.9, 0.8], np.float32)
    rgb = albedo * irradiance * (1 - 0.5 * metal[ids][..., None]) + 0.05 * metal[ids][..., None]
    return ArrayShot(
        {
            "albedo": albedo,
            "normal": normals[ids],
            "roughness": rough[ids][..., None],
            "metallic": metal[ids][..., None],
            "irradiance": irradiance,
            "rgb": rgb.astype(np.float32),
            "ids": ids[..., None],
        },
        caption=["a room in warm light", "a room in cool daylight"][seed % 2],
        object_captions={k: f"a {['red', 'green', 'blue', 'grey'][k % 4]} object number {k}" for k in range(1, objects + 1)},
        source=f"<tiny room {seed}>",
    )


def tiny_dataset(train: int = 2, test: int = 1, val: int = 0, **kw) -> dict[str, list[ArrayShot]]:
    out = {"train": [tiny_room(i, **kw) for i in range(train)], "test": [tiny_room(100 + i, **kw) for i in range(test)]}
    if val:
        out["val"] = [tiny_room(200 + i, **kw) for i in range(val)]
    return out


class FakeTextEncoder:
    """Deterministic stand-in for MiniLM in tests (384-d, seeded per prompt): loading MiniLM takes seconds."""

    dim = 384
    max_length = 8

    def encode(self, prompts):
        import zlib

        import torch

        if not prompts:
            return torch.zeros(0, self.max_length, self.dim)
        return torch.stack([torch.randn(self.max_length, self.dim, generator=torch.Generator().manual_seed(zlib.crc32(p.encode()))) for p in prompts])
