"""`Mask`: a per-frame region for local edits and local prompts (painted, propagated, or from object ids).

Mutation is deliberately small so an undo stack can wrap it: `paint(t, array)` replaces one
frame's painted array, `erase(t)` removes it (`set_painted` picks between them, `paint_frames` paints
many), `ids` is a plain list to assign (`add_id` appends one). Arrays are never
modified in place by this module; `paint` stores a float32 copy.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from x2video.shot import Shot

_FIELDS = {"ids", "hold", "frames", "file"}


@dataclass
class Mask:
    """A region per frame: the union of painted arrays and pixels whose object id is in `ids`.

    frames: frame index -> float32 (H, W) in [0, 1], sparse (painted or flow-propagated frames).
    ids: object ids (from the shot's `ids` channel) inside the mask on every frame.
    hold: a frame without a painted array uses the nearest earlier painted one (then the
        nearest later one); False means unpainted frames are empty (except `ids`).
    """

    frames: dict[int, np.ndarray] = field(default_factory=dict)
    ids: list[int] = field(default_factory=list)
    hold: bool = False

    def paint(self, t: int, array: np.ndarray) -> None:
        """Set (replace) the painted array of frame `t`: (H, W) values in [0, 1] (bool accepted)."""
        a = np.asarray(array)
        if a.ndim == 3 and a.shape[-1] == 1:
            a = a[..., 0]
        if a.ndim != 2:
            raise ValueError(f"mask frame {t}: expected an (H, W) array, got shape {a.shape}")
        if t < 0:
            raise ValueError(f"mask frame {t}: frame index must be >= 0")
        a = np.clip(np.nan_to_num(a.astype(np.float32)), 0.0, 1.0)
        self.frames[int(t)] = a

    def erase(self, t: int) -> None:
        """Remove frame `t`'s painted array (no-op when it has none)."""
        self.frames.pop(int(t), None)

    def paint_frames(self, frames: dict[int, np.ndarray]) -> None:
        """`paint` each frame of `frames` (what a propagation computed)."""
        for t, a in frames.items():
            self.paint(t, a)

    def set_painted(self, t: int, array: np.ndarray) -> None:
        """`paint` frame `t`, or `erase` it when `array` covers nothing (what a brush or an eraser leaves)."""
        if np.any(array):
            self.paint(t, array)
        else:
            self.erase(t)

    def painted(self, t: int, size: tuple[int, int]) -> np.ndarray:
        """A copy of frame `t`'s painted array, zeros of `size` (H, W) when it has none: what a brush starts from."""
        a = self.frames.get(int(t))
        return np.zeros(size, np.float32) if a is None else a.copy()

    def add_id(self, oid: int) -> None:
        """Put object `oid` inside the mask on every frame (no-op when it is already)."""
        if oid not in self.ids:
            self.ids = [*self.ids, int(oid)]

    def painted_frames(self) -> list[int]:
        return sorted(self.frames)

    def source_frame(self, t: int) -> int | None:
        """Which painted frame gives frame `t` its painted part (None: none)."""
        if t in self.frames:
            return t
        if not self.hold or not self.frames:
            return None
        before = [f for f in self.frames if f < t]
        return max(before) if before else min(self.frames)

    def at(self, shot: Shot, t: int) -> np.ndarray:
        """float32 (H, W) in [0, 1]: the mask on frame `t` of `shot`."""
        h, w = shot.size
        out = np.zeros((h, w), np.float32)
        src = self.source_frame(t)
        if src is not None:
            a = self.frames[src]
            if a.shape != (h, w):
                raise ValueError(f"mask painted on frame {src} has size {a.shape[1]}x{a.shape[0]}, the shot is {w}x{h}")
            out = a.copy()
        if self.ids:
            if not shot.has("ids"):
                raise ValueError(f"mask selects object ids {self.ids} but shot {shot.info.source!r} has no ids channel")
            sel = np.isin(shot.channel("ids", t)[..., 0], np.asarray(self.ids, dtype=np.int64))
            out = np.maximum(out, sel.astype(np.float32))
        return out

    # -- serialisation (arrays travel separately; see x2video.edits.project) ----------------
    def to_dict(self) -> dict[str, Any]:
        return {"ids": [int(i) for i in self.ids], "hold": bool(self.hold), "frames": self.painted_frames()}

    @classmethod
    def from_dict(cls, d: dict[str, Any], arrays: dict[int, np.ndarray] | None = None, where: str = "mask") -> "Mask":
        if not isinstance(d, dict):
            raise ValueError(f"{where}: expected an object")
        unknown = set(d) - _FIELDS
        if unknown:
            raise ValueError(f"{where}: unknown field(s) {', '.join(sorted(unknown))}")
        ids = d.get("ids", [])
        if not isinstance(ids, list) or not all(isinstance(i, int) and not isinstance(i, bool) for i in ids):
            raise ValueError(f"{where}.ids: expected a list of integers, got {ids!r}")
        m = cls(ids=list(ids), hold=bool(d.get("hold", False)))
        arrays = arrays or {}
        for t in d.get("frames", []):
            if not isinstance(t, int):
                raise ValueError(f"{where}.frames: frame index {t!r} is not an integer")
            if t not in arrays:
                raise ValueError(f"{where}: painted frame {t} has no array")
            m.paint(t, arrays[t])
        return m

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Mask):
            return NotImplemented
        return (
            self.ids == other.ids
            and self.hold == other.hold
            and self.frames.keys() == other.frames.keys()
            and all(np.array_equal(self.frames[k], other.frames[k]) for k in self.frames)
        )
