"""Frame schedules as pure functions: Recursive Sampling (paper Sec. Recursive Sampling) and the sequential baseline.

Recursive, for any length L >= 1 and window size N >= 2:

* K is the smallest level count with (N-1)^K >= span (span = L-1, or the longer side of the
  shot around a user reference frame). Level k has stride (N-1)^(k-1); the top stride is
  S = (N-1)^(K-1).
* Keyframes (level K, mode 'key'): frames 0, S, 2S, ... plus the last frame L-1 when it is
  off that grid. By the choice of K this is at most N frames, so one keyframe window covers
  the whole shot (N = 2 is the exception: a window has no room for an in-between frame,
  so the plan degenerates to a chain of 2-frame keyframe windows, each conditioned on the
  previous frame).
* Interpolation, level k = K-1 .. 1 (mode 'interp'): for each pair of adjacent frames (a, b)
  already produced with b - a > s (s = the level's stride), one window
  [a, a+s, a+2s, ..., b] conditioned on its two end frames, producing the frames in between.
  Gaps at level k are at most (N-1)*s, so a window has at most N frames.

Uneven tails: the grid is never stretched; where L-1 is not a multiple of the stride, the
last position of a window sits closer than the stride to its neighbour (positions are not
evenly spaced there) and such tail windows have fewer than N frames. Every other position
keeps the exact stride of its level, which is what the level's temporal LoRA was trained on.
No frame is generated twice.

With a user reference frame at index r, the grid is anchored at r: the first keyframe window
[r, r+S, ...] holds the reference at position 0 (and also produces frame r); frames before r
get a keyframe window running backwards in time [r, r-S, ...], conditioned on the produced
frame r (a static-scene camera path played backwards is still a camera path).

Sequential: windows of N consecutive frames; each window after the first starts with the
last frame of the previous one as its reference (keyframe mode, level 1). Tail windows are
shorter. With a reference frame the chain runs forwards and backwards from it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Mode = Literal["key", "interp", "seq"]


@dataclass(frozen=True)
class Window:
    """One sampler call over a window of frames."""

    frames: tuple[int, ...]
    """Shot frame index at each window position, in position order (backward windows descend)."""
    generate: tuple[int, ...]
    """Frames this window produces (a subset of `frames`, in position order)."""
    refs: tuple[int, ...]
    """Frames read as reference latents; all produced by earlier windows (position order)."""
    mode: Mode
    """'key' (keyframe prediction), 'interp' (interpolation between the two ends) or 'seq'."""
    level: int
    """Recursive level: K for keyframe windows, k for interpolation, 1 for sequential windows."""
    user_ref: bool = False
    """Position 0 carries the user's reference image (its frame is still generated)."""

    @property
    def ref_positions(self) -> tuple[int, ...]:
        """Window positions holding a reference latent: (), (0,) or (0, len-1)."""
        pos = {self.frames.index(f) for f in self.refs}
        if self.user_ref:
            pos.add(0)
        return tuple(sorted(pos))

    @property
    def generate_positions(self) -> tuple[int, ...]:
        return tuple(self.frames.index(f) for f in self.generate)


def num_levels(span: int, window: int) -> int:
    """K: the smallest k >= 1 with (N-1)^k >= span (1 for N = 2, which cannot interpolate)."""
    if window == 2:
        return 1
    k = 1
    while (window - 1) ** k < span:
        k += 1
    return k


def _grid(start: int, stop: int, stride: int) -> list[int]:
    """start, start±stride, ... towards stop (inclusive), plus stop itself when off the grid."""
    step = stride if stop >= start else -stride
    out = list(range(start, stop + (1 if step > 0 else -1), step))
    if out[-1] != stop:
        out.append(stop)
    return out


def _chain(frames: list[int], n: int, mode: Mode, level: int, first_produced: bool, user_ref: bool) -> list[Window]:
    """Windows over `frames` in order; each after the first starts at the previous window's last frame."""
    out: list[Window] = []
    i = 0
    if not first_produced:
        head = tuple(frames[:n])
        out.append(Window(head, head, (), mode, level, user_ref))
        i = len(head) - 1
    while i < len(frames) - 1:
        w = tuple(frames[i : i + n])
        out.append(Window(w, w[1:], (w[0],), mode, level))
        i += len(w) - 1
    return out


def _validate(length: int, window: int, ref_frame: int | None) -> int:
    if length < 1:
        raise ValueError(f"cannot plan a render of {length} frames (need at least 1)")
    if window < 2:
        raise ValueError(f"window size must be at least 2 frames, got {window}")
    if ref_frame is not None and not 0 <= ref_frame < length:
        raise ValueError(f"reference frame {ref_frame} outside the {length} frames being rendered")
    return 0 if ref_frame is None else ref_frame


def plan_recursive(length: int, window: int, ref_frame: int | None = None) -> list[Window]:
    """Recursive Sampling: keyframe window(s) at the widest stride, then interpolation level by level."""
    anchor = _validate(length, window, ref_frame)
    levels = num_levels(max(anchor, length - 1 - anchor), window)
    stride = (window - 1) ** (levels - 1)
    plan = _chain(_grid(anchor, length - 1, stride), window, "key", levels, False, ref_frame is not None)
    if anchor > 0:
        plan += _chain(_grid(anchor, 0, stride), window, "key", levels, True, False)
    produced = sorted({f for w in plan for f in w.generate})
    for level in range(levels - 1, 0, -1):
        s = (window - 1) ** (level - 1)
        new: list[int] = []
        for a, b in zip(produced, produced[1:]):
            if b - a <= s:
                continue
            inner = tuple(range(a + s, b, s))
            plan.append(Window((a, *inner, b), inner, (a, b), "interp", level))
            new.extend(inner)
        produced = sorted(produced + new)
    return plan


def plan_sequential(length: int, window: int, ref_frame: int | None = None) -> list[Window]:
    """Sequential baseline: consecutive windows, the last frame of one is the next one's reference."""
    anchor = _validate(length, window, ref_frame)
    plan = _chain(list(range(anchor, length)), window, "seq", 1, False, ref_frame is not None)
    if anchor > 0:
        plan += _chain(list(range(anchor, -1, -1)), window, "seq", 1, True, False)
    return plan


def plan(scheme: str, length: int, window: int, ref_frame: int | None = None) -> list[Window]:
    """`plan_recursive` or `plan_sequential` by name."""
    if scheme == "recursive":
        return plan_recursive(length, window, ref_frame)
    if scheme == "sequential":
        return plan_sequential(length, window, ref_frame)
    raise ValueError(f"unknown sampling scheme {scheme!r} (use 'recursive' or 'sequential')")


def last_use(windows: list[Window]) -> dict[int, int]:
    """Frame -> index of the last window that reads it as a reference (frames never read are absent).

    The Renderer keeps a frame's latent only until then.
    """
    out: dict[int, int] = {}
    for i, w in enumerate(windows):
        for f in w.refs:
            out[f] = i
    return out


def shift(windows: list[Window], offset: int) -> list[Window]:
    """The same plan over frames offset..offset+L-1 (rendering a sub-range of a shot)."""
    if offset == 0:
        return list(windows)

    def sh(fs: tuple[int, ...]) -> tuple[int, ...]:
        return tuple(f + offset for f in fs)

    return [Window(sh(w.frames), sh(w.generate), sh(w.refs), w.mode, w.level, w.user_ref) for w in windows]
