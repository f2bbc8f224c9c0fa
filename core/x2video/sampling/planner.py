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
No frame is generated twice, unless the seam pass is asked for (`seams=True`, our addition, not
the paper's): with three levels or more, right after the first interpolation level, each keyframe
is made again with its neighbours by an interpolation window of that level (`seam_windows`).

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
from typing import Literal, Sequence

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


def check_max_levels(max_levels: int | None) -> None:
    """The cap on Recursive Sampling's levels (`RenderSettings.max_levels`): None or at least 1."""
    if max_levels is not None and max_levels < 1:
        raise ValueError(f"max_levels must be at least 1, got {max_levels}")


def _validate(length: int, window: int, ref_frame: int | None) -> int:
    if length < 1:
        raise ValueError(f"cannot plan a render of {length} frames (need at least 1)")
    if window < 2:
        raise ValueError(f"window size must be at least 2 frames, got {window}")
    if ref_frame is not None and not 0 <= ref_frame < length:
        raise ValueError(f"reference frame {ref_frame} outside the {length} frames being rendered")
    return 0 if ref_frame is None else ref_frame


def seam_windows(keyframes: list[int], produced: list[int], length: int, window: int, stride: int, level: int,
                 anchor: int | None = None) -> list[Window]:
    """The seam pass: windows at `level` (stride `stride`, the first interpolation level) that
    re-generate each keyframe with its neighbours, before the finer levels read them.

    A keyframe comes from the top-level window, whose positions are N-1 times further apart than
    any interpolation window's, and the frames around it disagree with it more than with any other
    frame (`bench/recursive_seams.py`). For each keyframe f the pass adds one interpolation window
    (f-h*s, ..., f, ..., f+h*s), h = (N-1)//2, between two frames this level produced, which makes
    f and its neighbours again; the finer levels then interpolate between frames that all come
    from interpolation windows. At the shot's ends the window is one-sided: (f+h*s, ..., f) in
    keyframe mode, read backwards, for the first frame; (f-h*s, ..., f) for the last. A keyframe
    where the user's reference frame sits (`anchor`) keeps the reference: at a shot end its window
    is an interpolation window from the reference (position 0, also generated, as in the keyframe
    window) to f±h*s; elsewhere it is left as it is.

    Every frame of a seam window is one of `produced` (the frames made so far): the pass makes
    frames again, never early. Keyframes too close to another (their windows would make a frame
    twice) or to a shot end are left as they are.
    """
    h, s = (window - 1) // 2, stride
    if h < 1:  # N = 2: a window has no room for a frame between its ends
        return []
    have = set(produced)
    out: list[Window] = []
    taken: set[int] = set()
    for f in sorted(keyframes):
        lo, hi = f - h * s, f + h * s
        if f == anchor and f == 0 and hi <= length - 1:
            frames = tuple(range(0, hi + 1, s))
            win = Window(frames, frames[:-1], (hi,), "interp", level, user_ref=True)
        elif f == anchor and f == length - 1 and lo >= 0:
            frames = tuple(range(f, lo - 1, -s))
            win = Window(frames, frames[:-1], (lo,), "interp", level, user_ref=True)
        elif f == anchor:
            continue
        elif lo >= 0 and hi <= length - 1:
            frames = tuple(range(lo, hi + 1, s))
            win = Window(frames, frames[1:-1], (lo, hi), "interp", level)
        elif f == 0 and hi <= length - 1:  # first frame: backwards from f+h*s
            frames = tuple(range(hi, -1, -s))
            win = Window(frames, frames[1:], (hi,), "key", level)
        elif f == length - 1 and lo >= 0:  # last frame
            frames = tuple(range(lo, length, s))
            win = Window(frames, frames[1:], (lo,), "key", level)
        else:
            continue
        if taken & set(win.generate) or not set(win.frames) <= have:
            continue
        out.append(win)
        taken |= set(win.generate)
    return out


def plan_recursive(length: int, window: int, ref_frame: int | None = None, seams: bool = False,
                   max_levels: int | None = None) -> list[Window]:
    """Recursive Sampling: keyframe window(s) at the widest stride, then interpolation level by level;
    with `seams`, the seam pass (`seam_windows`) right after the first interpolation level when there
    are three levels or more (18 frames or more at N = 5). With two, the first interpolation level is
    the last, and the pass would double its windows to re-make keyframes only N-1 frames apart.

    The number of levels K is the fewest that let one keyframe window span the shot from the anchor
    (`num_levels`: 65 frames at N = 5 give K = 3, keyframes 16 apart, as in the paper's example), or
    `max_levels` when that is fewer: the keyframes are then (N-1)^(K-1) apart and the keyframe
    windows chained, each starting at the previous one's last keyframe (K = 2 at 65 frames: four
    keyframe windows at stride 4, then one interpolation level)."""
    anchor = _validate(length, window, ref_frame)
    check_max_levels(max_levels)
    levels = num_levels(max(anchor, length - 1 - anchor), window)
    if max_levels is not None:
        levels = min(levels, max_levels)
    stride = (window - 1) ** (levels - 1)
    plan = _chain(_grid(anchor, length - 1, stride), window, "key", levels, False, ref_frame is not None)
    if anchor > 0:
        plan += _chain(_grid(anchor, 0, stride), window, "key", levels, True, False)
    produced = sorted({f for w in plan for f in w.generate})
    keys = list(produced)
    for level in range(levels - 1, 0, -1):
        s = (window - 1) ** (level - 1)
        made = _interpolation_level(produced, s, level)
        plan += made
        produced = sorted(produced + [f for w in made for f in w.generate])
        if seams and levels >= 3 and level == levels - 1:
            plan += seam_windows(keys, produced, length, window, s, level, None if ref_frame is None else anchor)
    return plan


def _interpolation_level(produced: list[int], stride: int, level: int) -> list[Window]:
    """One interpolation level: a window [a, a+s, ..., b] between each pair of adjacent frames of `produced` (sorted)
    further apart than the stride s, conditioned on its two ends."""
    out: list[Window] = []
    for a, b in zip(produced, produced[1:]):
        if b - a > stride:
            inner = tuple(range(a + stride, b, stride))
            out.append(Window((a, *inner, b), inner, (a, b), "interp", level))
    return out


def plan_keyframed(length: int, window: int, keyframes: Sequence[int], scheme: str = "recursive",
                   max_levels: int | None = None) -> list[Window]:
    """Ref-Keyframe (paper Sec. Acceleration, table "Acceleration"): the keyframes are given (path-traced frames, read
    as references and never generated), which bypasses the keyframe stage; the plan makes every other frame.

    Recursive: the level count K is the fewest that let the first interpolation level (stride (N-1)^(K-2)) bridge
    every gap between adjacent keyframes in one window, and one keyframe-mode window (stride (N-1)^(K-1)) span the
    frames before the first keyframe and after the last. Those frames come first, from keyframe-mode windows that
    start at the first keyframe (running backwards in time) and at the last; then the interpolation levels K-1 .. 1
    run as in `plan_recursive`, so every top-level interpolation window between two keyframes has them as its two
    ends. `max_levels` below K: a gap wider than the keyframe stride first gets keyframe-mode windows chained from
    its first keyframe at that stride (stopping before the next keyframe), then the interpolation levels.
    Sequential: windows of consecutive frames chained from each keyframe towards the next (and from the first
    keyframe back to frame 0), each window's first frame its reference. No seam pass: the keyframes are exact.

    Frame numbers are 0..length-1; keyframes outside that range are refused (ValueError naming the first)."""
    _validate(length, window, None)
    check_max_levels(max_levels)
    keys = sorted(set(keyframes))
    if not keys:
        raise ValueError("a keyframed plan needs at least one keyframe")
    bad = [k for k in keys if not 0 <= k < length]
    if bad:
        raise ValueError(f"keyframe {bad[0]} outside the {length} frames being rendered")
    head, tail = keys[0], length - 1 - keys[-1]
    if scheme == "sequential":
        mode: Mode = "seq"
        levels = 1
    elif scheme == "recursive":
        mode = "key"
        need = [num_levels(b - a, window) + 1 for a, b in zip(keys, keys[1:]) if b - a > 1]
        need += [num_levels(span, window) for span in (head, tail) if span > 0]
        levels = 1 if window == 2 else max(need, default=1)
        if max_levels is not None:
            levels = min(levels, max_levels)
    else:
        raise ValueError(f"unknown sampling scheme {scheme!r} (use 'recursive' or 'sequential')")
    stride = (window - 1) ** (levels - 1)
    plan: list[Window] = []
    if tail > 0:
        plan += _chain(_grid(keys[-1], length - 1, stride), window, mode, levels, True, False)
    if head > 0:
        plan += _chain(_grid(keys[0], 0, stride), window, mode, levels, True, False)
    for a, b in zip(keys, keys[1:]):
        grid = list(range(a, b, stride))  # a, a+S, ... before b: made from a when the gap is wider than the stride
        if len(grid) > 1:
            plan += _chain(grid, window, mode, levels, True, False)
    produced = sorted(set(keys) | {f for w in plan for f in w.generate})
    for level in range(levels - 1, 0, -1):
        made = _interpolation_level(produced, (window - 1) ** (level - 1), level)
        plan += made
        produced = sorted(produced + [f for w in made for f in w.generate])
    return plan


def plan_sequential(length: int, window: int, ref_frame: int | None = None) -> list[Window]:
    """Sequential baseline: consecutive windows, the last frame of one is the next one's reference."""
    anchor = _validate(length, window, ref_frame)
    plan = _chain(list(range(anchor, length)), window, "seq", 1, False, ref_frame is not None)
    if anchor > 0:
        plan += _chain(list(range(anchor, -1, -1)), window, "seq", 1, True, False)
    return plan


def plan(scheme: str, length: int, window: int, ref_frame: int | None = None, seams: bool = False,
         max_levels: int | None = None) -> list[Window]:
    """`plan_recursive` or `plan_sequential` by name (`seams`: the recursive plan's seam pass;
    `max_levels`: its cap on the number of levels, checked for either scheme)."""
    check_max_levels(max_levels)
    if scheme == "recursive":
        return plan_recursive(length, window, ref_frame, seams, max_levels)
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
