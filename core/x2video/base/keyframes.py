"""Which frames are keyframes: `--keyframes every:N|LIST` on a fully rendered shot, so the frames between can be scored.

A keyframe shot carries path-traced rgb on some frames only (`ShotInfo.rgb_frames`); `only_keyframes` makes one from
any shot with rgb on every frame, keeping rgb on the frames named and hiding it on the others, which then render from
their keyframes as a shot exported with keyframes would.
"""
from __future__ import annotations

import sys
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from x2video.shot import Shot

if TYPE_CHECKING:
    from x2video.render.settings import RenderSettings


def parse_keyframes(text: str, num_frames: int) -> tuple[int, ...]:
    """'every:8' -> 0, 8, 16, ... and the last frame; '0,8,20' -> those frames. ValueError names what is wrong."""
    text = text.strip()
    if text.startswith("every:"):
        try:
            n = int(text[len("every:"):])
        except ValueError:
            raise ValueError(f"--keyframes {text!r}: expected every:N with N a whole number") from None
        if n < 1:
            raise ValueError(f"--keyframes {text!r}: N must be at least 1")
        frames = list(range(0, num_frames, n))
        if frames[-1] != num_frames - 1:
            frames.append(num_frames - 1)
        return tuple(frames)
    try:
        frames = sorted({int(v) for v in text.split(",") if v.strip()})
    except ValueError:
        raise ValueError(f"--keyframes {text!r}: expected every:N or a comma-separated list of frame numbers") from None
    if not frames:
        raise ValueError("--keyframes: no frames given")
    if frames[0] < 0:
        raise ValueError(f"--keyframes: frame {frames[0]} is negative (frames are numbered from 0)")
    bad = [f for f in frames if not 0 <= f < num_frames]
    if bad:
        raise ValueError(f"--keyframes: frame {bad[0]} is outside the shot's {num_frames} frames (0..{num_frames - 1})")
    return tuple(frames)


def check_keyframes(text: object) -> None:
    """ValueError naming --keyframes unless `text` reads as every:N or a list of frame numbers (what needs no shot:
    whether the frames lie inside it is `parse_keyframes`'s)."""
    if not isinstance(text, str):
        raise ValueError(f"--keyframes: expected every:N or a comma-separated list of frame numbers, got {text!r}")
    if text.strip().startswith("every:"):
        parse_keyframes(text, 1)
        return
    parse_keyframes(text, sys.maxsize)


class KeyframeShot(Shot):
    """`shot` with rgb only on `frames` (they must carry rgb in `shot`)."""

    def __init__(self, shot: Shot, frames: tuple[int, ...]) -> None:
        missing = [f for f in frames if not shot.has_rgb(f)]
        if missing:
            raise ValueError(f"shot {shot.info.source!r}: frame {missing[0]} has no rgb to be a keyframe")
        self.base_shot = shot
        self.info = replace(shot.info, rgb_frames=tuple(sorted(frames)))

    def _read(self, name: str, t: int) -> np.ndarray:
        return self.base_shot.channel(name, t)

    def __getattr__(self, name: str):
        return getattr(self.base_shot, name)  # a loader's extras (motion, frame_path)


def only_keyframes(shot: Shot, spec: str) -> Shot:
    """`shot` with rgb kept on the keyframes `spec` names (`parse_keyframes`); ValueError when it has no rgb."""
    if not shot.has("rgb"):
        raise ValueError(f"--keyframes: shot {shot.info.source!r} has no rgb channel to take keyframes from")
    frames = parse_keyframes(spec, shot.num_frames)
    return KeyframeShot(shot, frames)


def keyframed(shot: Shot, settings: RenderSettings) -> Shot:
    """`shot` with rgb kept on `RenderSettings.keyframes` only (`only_keyframes`), or as it is when unset: the frames
    that are a render's base (`x2video.base.stage`)."""
    return shot if settings.keyframes is None else only_keyframes(shot, settings.keyframes)


def reference_keyframes(shot: Shot, settings: RenderSettings) -> tuple[int, ...]:
    """The keyframes a render of `shot` with `settings` gives the diffusion tier as references (`RenderSettings.fill`
    'diffusion', base 'auto'): the shot's rgb frames, or the `keyframes` setting's; () when the fill is classical, the
    base is off, or no frame is left to fill (no rgb, or rgb on every frame)."""
    if settings.fill != "diffusion" or settings.base != "auto":
        return ()
    keys = tuple(shot.keyframes) if settings.keyframes is None else parse_keyframes(settings.keyframes, shot.num_frames)
    return keys if 0 < len(keys) < shot.num_frames else ()
