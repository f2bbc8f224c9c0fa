"""Training data on disk: the train/val/test room folders of `x2video dataset make`, and frames resized to the training size.

A data set folder holds one shot folder per room (docs/SHOT_FORMAT.md) under `train/`, `val/` (validation rooms,
never trained on: what the stages' held-out figures read, so runs are compared and chosen on them) and `test/`
(held-out rooms the reported figures read, never trained on). A set without `val/` holds out on `test/`, as sets
made before validation rooms existed. A folder of shot folders without the split sub-folders is read as one split.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from x2video.io.dataset import shot_dirs
from x2video.shot import Shot

SPLITS = ("train", "val", "test")


def open_split(data_dir: str | Path, split: str) -> list[Shot]:
    """Lazily opened shots of one split (`x2video.io.load_shot`)."""
    from x2video.io import load_shot

    return [load_shot(p) for p in shot_dirs(data_dir, split)]


def open_dataset(data_dir: str | Path, need_test: bool = True) -> dict[str, list[Shot]]:
    """{'train': [...], 'val': [...], 'test': [...]} shots of a data set folder ('val' only when it has validation
    rooms); errors name what is missing."""
    out = {s: open_split(data_dir, s) for s in SPLITS}
    if not out["val"]:
        del out["val"]
    if not out["train"]:
        raise FileNotFoundError(f"{data_dir}: no training rooms (expected {Path(data_dir) / 'train'}/<room>/shot.json)")
    if need_test and not out["test"] and "val" not in out:
        raise FileNotFoundError(f"{data_dir}: no held-out rooms (expected {Path(data_dir) / 'val'}/<room>/shot.json or"
                                f" {Path(data_dir) / 'test'}/<room>/shot.json)")
    return out


def heldout_split(splits) -> str:
    """The split a stage's held-out figures read: 'val' when the data set (or latent cache) has validation rooms, else
    'test'. Runs are compared, and their settings chosen, on validation rooms; the test rooms are for the reported
    figures only (issue 49)."""
    return "val" if "val" in splits else "test"


def resize_channel(name: str, x: np.ndarray, size: tuple[int, int] | None) -> np.ndarray:
    """One channel (H, W, C) -> (h, w, C) at size=(w, h): area averaging (normals re-normalised),
    nearest neighbour for object ids. Returns the input when the size already matches."""
    if size is None or (x.shape[1], x.shape[0]) == tuple(size):
        return x
    w, h = size
    if name == "ids":
        y = cv2.resize(x[..., 0].astype(np.int32), (w, h), interpolation=cv2.INTER_NEAREST)
        return y[..., None]
    if x.shape[0] < h or x.shape[1] < w:
        interp = cv2.INTER_LINEAR
    else:
        interp = cv2.INTER_AREA
    y = cv2.resize(np.ascontiguousarray(x, np.float32), (w, h), interpolation=interp)
    if y.ndim == 2:
        y = y[..., None]
    if name == "normal":
        n = np.linalg.norm(y, axis=-1, keepdims=True)
        y = np.where(n > 1e-3, y / np.maximum(n, 1e-6), 0.0).astype(np.float32)
    return y


def even_frames(shot: Shot, count: int) -> list[int]:
    """Up to `count` evenly spaced frame indices of `shot`, first and last included (the pools of the
    VAE and encoder stages)."""
    return [int(t) for t in np.unique(np.linspace(0, shot.num_frames - 1, min(count, shot.num_frames)).round().astype(int))]


def read_frame(shot: Shot, t: int, names: tuple[str, ...], size: tuple[int, int] | None) -> dict[str, np.ndarray]:
    """The named channels of frame t at `size`; a missing channel raises naming the shot and frame."""
    out = {}
    for name in names:
        if not shot.has(name):
            raise ValueError(f"shot {shot.info.source!r} frame {t}: channel {name!r} is missing; training needs it")
        out[name] = resize_channel(name, shot.channel(name, t), size)
    return out
