"""Side-by-side renders of held-out shots (ground truth | image model | video model) as a PNG contact sheet and an MP4.

What the model card shows a reader: a contact sheet has one row per source and one column
per sampled frame, each row labelled; the MP4 plays the sources side by side. Frames arrive
linear and are shown through `x2video.channels.tonemap`, like the metrics see them.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from x2video.channels import tonemap
from x2video.io.atomic import write_bytes_atomic
from x2video.io.writers import MP4Writer

_LABEL_H = 14


def _u8(frame: np.ndarray) -> np.ndarray:
    return np.round(tonemap(np.asarray(frame, np.float32)) * 255).astype(np.uint8)  # (H, W, 3)


def _label(width: int, text: str) -> np.ndarray:
    """(14, width, 3) dark strip with white text."""
    strip = np.full((_LABEL_H, width, 3), 24, np.uint8)
    cv2.putText(strip, text, (3, _LABEL_H - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (235, 235, 235), 1, cv2.LINE_AA)
    return strip


def pick_frames(num_frames: int, count: int = 5) -> list[int]:
    """`count` evenly spaced frame indices including the first and last."""
    if num_frames <= count:
        return list(range(num_frames))
    return sorted({round(i * (num_frames - 1) / (count - 1)) for i in range(count)})


def contact_sheet(sources: Sequence[tuple[str, Sequence[np.ndarray]]], frames: Sequence[int], gap: int = 2) -> np.ndarray:
    """uint8 RGB sheet: one labelled row per (label, linear frames) source, one column per index in `frames`."""
    if not sources:
        raise ValueError("contact sheet: no sources")
    h, w = np.asarray(sources[0][1][0]).shape[:2]
    width = len(frames) * w + (len(frames) - 1) * gap
    rows = []
    for label, seq in sources:
        if len(seq) <= max(frames):
            raise ValueError(f"contact sheet: source {label!r} has {len(seq)} frames, frame {max(frames)} asked")
        tiles = []
        for i, t in enumerate(frames):
            f = np.asarray(seq[t])
            if f.shape[:2] != (h, w):
                raise ValueError(f"contact sheet: source {label!r} frame {t} is {f.shape[1]}x{f.shape[0]}, expected {w}x{h}")
            tiles.append(_u8(f))
            if i < len(frames) - 1:
                tiles.append(np.full((h, gap, 3), 255, np.uint8))
        rows += [_label(width, f"{label}  (frames {', '.join(map(str, frames))})"), np.concatenate(tiles, axis=1)]
    return np.concatenate(rows, axis=0)


def side_by_side(sources: Sequence[tuple[str, Sequence[np.ndarray]]], t: int, gap: int = 2) -> np.ndarray:
    """uint8 RGB frame t of all sources next to each other, each with its label on top."""
    tiles = []
    for i, (label, seq) in enumerate(sources):
        img = _u8(seq[t])
        tiles.append(np.concatenate([_label(img.shape[1], label), img], axis=0))
        if i < len(sources) - 1:
            tiles.append(np.full((tiles[-1].shape[0], gap, 3), 255, np.uint8))
    return np.concatenate(tiles, axis=1)


def write_comparison(out_dir: str | Path, name: str, sources: Sequence[tuple[str, Sequence[np.ndarray]]], fps: float = 10.0,
                     frames: int = 5) -> tuple[Path, Path]:
    """Write OUT/name.png (contact sheet of `frames` sampled frames) and OUT/name.mp4 (side by side), atomically."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    n = min(len(seq) for _, seq in sources)
    sheet = contact_sheet(sources, pick_frames(n, frames))
    ok, png = cv2.imencode(".png", cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError(f"{out / name}.png: PNG encoding failed")
    png_path = out / f"{name}.png"
    write_bytes_atomic(png_path, png.tobytes())
    mp4_path = out / f"{name}.mp4"
    with MP4Writer(mp4_path, fps) as w:
        for t in range(n):
            w.write(side_by_side(sources, t))
    return png_path, mp4_path
