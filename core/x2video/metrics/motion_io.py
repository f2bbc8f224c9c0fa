"""Reads a shot folder's exact motion (`motion/000000.exr`, docs/SHOT_FORMAT.md) for the TC metric."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

_NUMBER = re.compile(r"(\d+)\.exr$", re.IGNORECASE)


def _component(names: tuple[str, ...], comp: str, path: Path) -> int:
    for i, n in enumerate(names):
        if n == comp or n.endswith("." + comp):
            return i
    raise ValueError(f"{path}: no motion channel {comp!r} (channels: {', '.join(names)})")


def read_motion_frame(path: str | Path) -> np.ndarray:
    """One motion EXR -> float32 (H, W, 2) pixel displacement (x right, y down), NaN kept.

    Channels are found by name (X and Y, or ``*.X``/``*.Y``): EXR stores them sorted by name."""
    import OpenImageIO as oiio

    path = Path(path)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise FileNotFoundError(f"{path}: cannot open motion EXR ({oiio.geterror()})")
    try:
        names = tuple(inp.spec().channelnames)
        data = inp.read_image(format="float")
    finally:
        inp.close()
    if data is None:
        raise ValueError(f"{path}: cannot read pixels")
    ix, iy = _component(names, "X", path), _component(names, "Y", path)
    return np.ascontiguousarray(np.stack([data[..., ix], data[..., iy]], axis=-1), dtype=np.float32)


def read_motion(shot_dir: str | Path, num_frames: int | None = None) -> np.ndarray | None:
    """(T-1, H, W, 2) motion of a shot folder, or None when it has no `motion/` folder.

    Files are numbered consecutively from 0; a file for the last frame, if present, is ignored
    (the last frame has no successor). With `num_frames` the count is checked."""
    folder = Path(shot_dir) / "motion"
    if not folder.is_dir():
        return None
    files = sorted((int(m.group(1)), p) for p in folder.iterdir() if (m := _NUMBER.search(p.name)))
    numbers = [n for n, _ in files]
    if numbers != list(range(len(numbers))):
        raise ValueError(f"{folder}: motion frames must be numbered 0..N-1 without gaps, found {numbers[:5]}...")
    if num_frames is not None:
        if len(files) < num_frames - 1:
            raise ValueError(f"{folder}: {len(files)} motion frames for a shot of {num_frames} frames (need {num_frames - 1})")
        files = files[: num_frames - 1]
    if not files:
        raise ValueError(f"{folder}: no motion EXR files")
    return np.stack([read_motion_frame(p) for _, p in files])
