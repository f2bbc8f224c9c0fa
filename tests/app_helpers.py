"""Shared set-up for the editor tests: a small shot folder on disk and a main window that never blocks on dialogs."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from x2video.io import ShotWriter
from x2video.shot import ArrayShot


def make_shot_dir(root: Path, frames: int = 9, h: int = 64, w: int = 96, name: str = "shot") -> Path:
    """A procedural-looking shot folder: two objects (ids 1, 2) sliding right over a floor, all channels."""
    rng = np.random.default_rng(0)
    ids = np.zeros((frames, h, w, 1), np.int32)
    for t in range(frames):
        ids[t, h // 2 :, :] = 3  # floor
        ids[t, 8:30, 6 + 2 * t : 30 + 2 * t] = 1
        ids[t, 34:56, 50 + t : 80 + t] = 2
    palette = np.array([[0.1, 0.1, 0.1], [0.7, 0.2, 0.1], [0.1, 0.3, 0.8], [0.5, 0.5, 0.45]], np.float32)
    albedo = palette[ids[..., 0]]
    normal = np.zeros((frames, h, w, 3), np.float32)
    normal[..., 2] = 1.0
    rough = np.full((frames, h, w, 1), 0.6, np.float32)
    metal = (ids == 2).astype(np.float32)
    irr = np.clip(0.6 + 0.1 * rng.standard_normal((1, h, w, 3)), 0, None).astype(np.float32).repeat(frames, 0)
    rgb = albedo * irr
    shot = ArrayShot({"albedo": albedo, "normal": normal, "roughness": rough, "metallic": metal, "irradiance": irr, "ids": ids, "rgb": rgb},
                     caption="a small test room", object_captions={1: "a red box", 2: "a blue metal box"})
    out = root / name
    with ShotWriter(out, shot.info) as wr:
        for t in range(frames):
            wr.write_frame(t, shot.frame(t))
    return out
