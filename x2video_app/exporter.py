"""Export of a render: MP4 (H.264, sRGB) and an EXR shot folder (rendered RGB, optionally the edited channels).

Rendered frames are in the model's exposure; `x2video.io.units.OutputUnits` (the same as the CLI's)
takes them to the input's units for EXR and to the chosen exposure for MP4.

Generators: each yields the number of frames written so far, so a superqt generator worker can
drive a progress dialog and stop between frames (`quit()`). Writes are atomic: the MP4 appears
under its name only when complete; the EXR folder writes every image atomically and its
shot.json last (a folder without shot.json is unfinished).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from x2video.channels import INTRINSIC
from x2video.io import ShotWriter
from x2video.io.units import OutputUnits
from x2video.io.writers import MP4Writer
from x2video.shot import Shot


def export_mp4(frames: dict[int, np.ndarray], path: Path, fps: float, units: OutputUnits | None = None) -> Iterator[int]:
    """Rendered linear RGB frames (any order in the dict) -> H.264 MP4 in frame order, tone-mapped at `units`' exposure."""
    units = units if units is not None else OutputUnits()
    order = sorted(frames)
    w = MP4Writer(path, fps, encode="srgb")
    try:
        for k, t in enumerate(order):
            w.write(units.display(frames[t]))
            yield k + 1
        w.close()
    except BaseException as exc:  # includes GeneratorExit when the worker is told to quit
        w.abort(exc if isinstance(exc, Exception) else None)
        raise


def export_exr(frames: dict[int, np.ndarray], out_dir: Path, shot: Shot, edits: Any = None, units: OutputUnits | None = None) -> Iterator[int]:
    """A shot folder: `rgb/` = the render (linear, half), plus the edited intrinsic channels when `edits` is given,
    all in the input's units (irradiance too: shot.json then says it is not normalised, as the input was not)."""
    from x2video.edits import apply_edits

    units = units if units is not None else OutputUnits.for_shot(shot)

    n = len(frames)
    if sorted(frames) != list(range(n)) or n != shot.num_frames:
        raise ValueError(f"EXR export needs every frame of the shot rendered ({len(frames)} of {shot.num_frames})")
    extra = {**shot.info.extra, "x2video:rendered": True, "x2video:irradiance_scale": units.irradiance_scale}
    info = dataclasses.replace(shot.info, channels=("rgb",), source=str(out_dir), extra=extra, irradiance_scale=1.0)
    with ShotWriter(out_dir, info, overwrite=True, irradiance_normalized=units.irradiance_scale == 1.0) as w:
        for t in range(n):
            chans: dict[str, np.ndarray] = {"rgb": units.scene(frames[t])}
            if edits is not None:
                cond = apply_edits(shot, edits, t)
                chans.update({c: a for c in INTRINSIC if (a := cond.channels.get(c)) is not None})
                if "irradiance" in chans:
                    chans["irradiance"] = units.scene(chans["irradiance"])
            w.write_frame(t, chans)
            yield t + 1
