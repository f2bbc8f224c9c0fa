"""Held-out shots for evaluation (paper Sec. Test Data): the test rooms, cut to T frames and area-resized to the model's size.

The ground truth is each shot's `rgb/` channel (linear HDR radiance), or, for a path-traced shot given a truth
apart from its passes (``truth/``, `x2video dataset truth`: more samples, another noise seed), that truth;
compared display-referred after `x2video.channels.tonemap` (as every metric in
`x2video.metrics` does). When the model was trained at a smaller size than the data, the
channels, the ground truth and the exact motion are all area-downsampled to the model's size
(object ids by nearest neighbour, motion vectors scaled with the image), and the results say so.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from x2video.io.truth import OWN, ground_truth
from x2video.shot import Shot, ShotInfo

log = logging.getLogger(__name__)

GROUND_TRUTH = (
    "the shot's rgb/ channel (linear HDR radiance), or its truth apart (truth/: more samples, another noise seed than "
    "the passes; results' 'truth' says which), compared after "
    "x2video.channels.tonemap (clip to [0, 1], sRGB), like every prediction"
)


class EvalView(Shot):
    """The first `frames` frames of `shot`, every channel resized to `size` = (W, H) (None: as is)."""

    def __init__(self, shot: Shot, frames: int | None = None, size: tuple[int, int] | None = None) -> None:
        from x2video.train.data import resize_channel

        self._shot, self._resize = shot, resize_channel
        n = shot.num_frames if frames is None else min(frames, shot.num_frames)
        if n < 1:
            raise ValueError(f"shot {shot.info.source!r}: no frames to evaluate")
        h, w = shot.size
        self.target = None if size is None or tuple(size) == (w, h) else (int(size[0]), int(size[1]))
        H, W = (h, w) if self.target is None else (self.target[1], self.target[0])
        i = shot.info
        self.info = ShotInfo(
            num_frames=n, height=H, width=W, channels=i.channels, fps=i.fps, caption=i.caption,
            object_captions=dict(i.object_captions), poses=None if i.poses is None else i.poses[:n],
            irradiance_scale=i.irradiance_scale, source=i.source, extra=dict(i.extra),
        )

    def _read(self, name: str, t: int) -> np.ndarray:
        return self._resize(name, self._shot.channel(name, t), self.target)


def resize_motion(motion: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(T-1, H, W, 2) pixel motion (NaN = occluded) -> (T-1, h, w, 2) at size = (w, h).

    Area average of the valid vectors, scaled by the size ratio per axis; a small pixel any of
    whose source pixels is invalid stays NaN (occlusion is never averaged away)."""
    t, H, W, _ = motion.shape
    w, h = size
    if (W, H) == (w, h):
        return motion
    out = np.empty((t, h, w, 2), np.float32)
    scale = np.array([w / W, h / H], np.float32)
    for i in range(t):
        m = motion[i]
        valid = np.isfinite(m).all(axis=-1).astype(np.float32)  # (H, W)
        filled = np.where(valid[..., None] > 0, m, 0.0).astype(np.float32)
        avg = cv2.resize(filled, (w, h), interpolation=cv2.INTER_AREA)  # (h, w, 2)
        frac = cv2.resize(valid, (w, h), interpolation=cv2.INTER_AREA)  # (h, w)
        v = avg / np.maximum(frac, 1e-6)[..., None] * scale
        out[i] = np.where((frac > 1 - 1e-4)[..., None], v, np.nan)
    return out


@dataclass
class EvalShot:
    """One held-out shot as the evaluation uses it."""

    name: str
    path: Path
    shot: Shot  # an EvalView: T frames at the evaluation size
    motion: np.ndarray | None  # (T-1, H, W, 2) exact motion at the evaluation size, None -> DIS flow
    gt: list[np.ndarray] = field(default_factory=list)  # T linear (H, W, 3) ground-truth frames
    #: which truth `gt` is (`x2video.io.truth.label`): 'apart, 64 spp seed 1' or the shot's own rgb
    truth: str = OWN

    @property
    def num_frames(self) -> int:
        return self.shot.num_frames


def load_eval_shots(
    data_dir: str | Path,
    split: str = "test",
    rooms: int | None = None,
    frames: int | None = None,
    size: tuple[int, int] | None = None,
) -> list[EvalShot]:
    """The first `rooms` shots of `data_dir/split` (sorted by name), each cut to `frames` frames and
    resized to `size` = (W, H). Every shot must carry rgb (ground truth)."""
    from x2video.io import load_shot
    from x2video.io.dataset import shot_dirs
    from x2video.metrics import read_motion

    dirs = shot_dirs(data_dir, split)
    if not dirs:
        raise FileNotFoundError(f"{data_dir}: no shots in split {split!r} (expected {Path(data_dir) / split}/<room>/shot.json)")
    if rooms is not None:
        if rooms < 1:
            raise ValueError(f"--rooms must be at least 1, got {rooms}")
        dirs = dirs[:rooms]
    out = []
    for d in dirs:
        view = EvalView(load_shot(d), frames, size)
        if not view.has("rgb"):
            raise ValueError(f"{d}: held-out shot has no rgb/ ground truth")
        n = view.num_frames
        motion = read_motion(d, n) if n >= 2 else None
        if motion is not None and view.target is not None:
            motion = resize_motion(motion, view.target)
        truth = ground_truth(view._shot, d)  # truth/ beside the frames (rendered apart from the passes) when there, else rgb
        gt = [view._resize("rgb", truth.frame(t), view.target) for t in range(n)]
        out.append(EvalShot(d.name, d, view, motion, gt, truth.label))
    return out


def native_size(data_dir: str | Path, split: str = "test") -> tuple[int, int]:
    """(W, H) of the first shot of a split (what `dataset make --size` wrote)."""
    from x2video.io.dataset import shot_dirs

    dirs = shot_dirs(data_dir, split)
    if not dirs:
        raise FileNotFoundError(f"{data_dir}: no shots in split {split!r}")
    doc = json.loads((dirs[0] / "shot.json").read_text())
    return int(doc["width"]), int(doc["height"])


def training_size(weights: str | Path) -> tuple[int, int] | None:
    """(W, H) the model at `weights` was trained at, when the folder records it, else None.

    Looked up in order: `training.json` {"size": [W, H]} in the model folder (for shipped
    weights); for a training run's `step-*/model/`, the run's `state.json` stage config ->
    its latent cache's `meta.json` size (an encoder run's: its teacher's)."""
    p = Path(weights)
    for doc in (p / "training.json", p.parent / "training.json"):
        if doc.is_file():
            size = json.loads(doc.read_text()).get("size")
            if size:
                return int(size[0]), int(size[1])
    for state in (p.parent / "state.json", p / "state.json"):
        if state.is_file():
            stage_config = json.loads(state.read_text()).get("stage_config", {})
            teacher = stage_config.get("teacher") if stage_config.get("stage") == "encoder" else None
            if teacher and Path(teacher).resolve() != p.resolve():  # an encoder run: its teacher's size
                return training_size(teacher)
            cache = stage_config.get("cache")
            meta = Path(cache) / "meta.json" if cache else None
            if meta is not None and meta.is_file():
                size = json.loads(meta.read_text()).get("size")
                if size:
                    return int(size[0]), int(size[1])
            elif meta is not None:
                log.warning("%s names latent cache %s, which is gone; training size unknown", state, cache)
    return None
