"""`Shot`: a sequence of T frames of intrinsic channels in one memory convention, read lazily.

A shot never holds all its frames: `frame(t)` / `channel(name, t)` read from the source
each time (loaders may keep a small LRU cache). Missing channels are simply absent from
`channels`; the model treats them as dropped. A channel that only some frames carry (a keyframe shot's light passes,
path-traced with its rgb on the keyframes only) is not in `channels` but in `ShotInfo.channel_frames`: read on those
frames, a KeyError naming channel and frame elsewhere (`has(name, t)` says which).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Iterator, Mapping

import numpy as np

from x2video.channels import SPECS


@dataclass
class CameraPose:
    """One frame's camera: 4x4 camera-to-world matrix in OpenGL convention (camera looks down -Z,
    +Y up, +X right; Blender's ``camera.matrix_world``) and the vertical field of view in degrees."""

    cam_to_world: np.ndarray
    fov_y_deg: float | None = None


@dataclass
class ShotInfo:
    """What describes a shot besides its pixels."""

    num_frames: int
    height: int
    width: int
    channels: tuple[str, ...]
    fps: float = 10.0
    #: per-shot caption (light mood and style), per-object captions keyed by object id
    caption: str = ""
    object_captions: dict[int, str] = field(default_factory=dict)
    #: one pose per frame, or None when the source has none
    poses: list[CameraPose] | None = None
    #: the irradiance exposure normalisation applied to every frame of this shot (docs/ARCHITECTURE.md
    #: "Channel convention": computed once per shot). 1.0 when no normalisation was applied.
    irradiance_scale: float = 1.0
    source: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    #: the frames that carry path-traced rgb (keyframes: Cycles rendered 1 frame in N, the rest are G-buffers
    #: only), sorted; None when every frame of a shot with an rgb channel carries it
    rgb_frames: tuple[int, ...] | None = None
    #: channels that only some frames carry, each with those frames (sorted): a keyframe shot's light passes
    #: (irradiance, diffuse_color, glossy), rendered with its rgb. Not in `channels`, which every frame carries (rgb
    #: aside: `rgb_frames`)
    channel_frames: dict[str, tuple[int, ...]] = field(default_factory=dict)


class Shot(ABC):
    """Base class: subclasses implement `_read(name, t)` returning an array in memory convention."""

    info: ShotInfo

    # -- what every user calls -------------------------------------------------
    @property
    def num_frames(self) -> int:
        return self.info.num_frames

    def __len__(self) -> int:
        return self.info.num_frames

    @property
    def size(self) -> tuple[int, int]:
        """(height, width)"""
        return self.info.height, self.info.width

    @property
    def channels(self) -> tuple[str, ...]:
        return self.info.channels

    def has(self, name: str, t: int | None = None) -> bool:
        """The shot has channel `name` (on every frame, rgb on some: `has_rgb`); with `t`, frame t carries it (a channel
        of `ShotInfo.channel_frames` on its frames too)."""
        if t is None:
            return name in self.info.channels
        if name == "rgb":
            return self.has_rgb(t)
        return name in self.info.channels or t in self.info.channel_frames.get(name, ())

    def frames_with(self, name: str) -> tuple[int, ...]:
        """The frames that carry channel `name`, in order (every frame, the keyframes for rgb, none for a channel it lacks)."""
        if name == "rgb":
            return self.keyframes
        if name in self.info.channels:
            return tuple(range(self.num_frames))
        return tuple(self.info.channel_frames.get(name, ()))

    def has_rgb(self, t: int) -> bool:
        """Frame t carries the shot's own path-traced rgb (every frame of a shot with rgb, or a keyframe)."""
        if "rgb" not in self.info.channels:
            return False
        return self.info.rgb_frames is None or t in self.info.rgb_frames

    @property
    def keyframes(self) -> tuple[int, ...]:
        """The frames that carry rgb, in order (all frames when every one does; none without rgb)."""
        if "rgb" not in self.info.channels:
            return ()
        return tuple(range(self.num_frames)) if self.info.rgb_frames is None else self.info.rgb_frames

    def channel(self, name: str, t: int) -> np.ndarray:
        """One channel of frame t: float32 (H, W, C) (int32 for ids), in the convention of docs/ARCHITECTURE.md."""
        some = self.info.channel_frames.get(name)
        if name not in self.info.channels and some is None:
            raise KeyError(f"shot {self.info.source!r} has no channel {name!r} (has {', '.join(self.info.channels)})")
        if not 0 <= t < self.info.num_frames:
            raise IndexError(f"frame {t} outside shot {self.info.source!r} of {self.info.num_frames} frames")
        if name == "rgb" and not self.has_rgb(t):
            raise KeyError(f"shot {self.info.source!r}: frame {t} has no rgb (keyframes: {_frames_text(self.keyframes)})")
        if some is not None and name not in self.info.channels and t not in some:
            raise KeyError(f"shot {self.info.source!r}: frame {t} has no {name} (only frames {_frames_text(some)} carry it)")
        return self._read(name, t)

    def frame(self, t: int, names: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
        """The shot's channels of frame t (`channels`; rgb only where frame t carries it, `has_rgb`), or those of `names`
        that frame t carries (a channel of `ShotInfo.channel_frames` on its frames)."""
        names = self.info.channels if names is None else names
        return {n: self.channel(n, t) for n in names if self.has(n, t)}

    def __iter__(self) -> Iterator[dict[str, np.ndarray]]:
        for t in range(self.info.num_frames):
            yield self.frame(t)

    # -- for subclasses --------------------------------------------------------
    @abstractmethod
    def _read(self, name: str, t: int) -> np.ndarray:
        """Read one channel of one frame from the source, already in memory convention."""


def _frames_text(frames: tuple[int, ...], most: int = 12) -> str:
    """'0, 8, 16' (the first `most`, then how many more)."""
    head = ", ".join(str(f) for f in frames[:most])
    return head + (f" and {len(frames) - most} more" if len(frames) > most else "") if frames else "none"


class ArrayShot(Shot):
    """A shot held in memory (tests, procedural previews, the editor's small clips)."""

    def __init__(self, arrays: Mapping[str, np.ndarray], **info: Any):
        arrays = {k: np.asarray(v) for k, v in arrays.items()}
        if not arrays:
            raise ValueError("ArrayShot needs at least one channel")
        shapes = {k: v.shape for k, v in arrays.items()}
        t, h, w = next(iter(arrays.values())).shape[:3]
        for k, v in arrays.items():
            if k not in SPECS:
                raise ValueError(f"unknown channel {k!r}")
            if v.ndim == 3:
                arrays[k] = v = v[..., None]
            if v.shape[:3] != (t, h, w):
                raise ValueError(f"channel {k!r} has shape {v.shape}, others {shapes}")
            if v.shape[3] != SPECS[k].components:
                raise ValueError(f"channel {k!r} has {v.shape[3]} components, expected {SPECS[k].components}")
        self._arrays = {k: v.astype(SPECS[k].dtype, copy=False) for k, v in arrays.items()}
        order = [c for c in SPECS if c in arrays]
        self.info = ShotInfo(num_frames=t, height=h, width=w, channels=tuple(order), source=info.pop("source", "<memory>"), **info)

    def _read(self, name: str, t: int) -> np.ndarray:
        return self._arrays[name][t]
