"""Qt-free record of one render as its events arrive: frames, their levels, keyframes, per-level progress, ETA,
and the formula's preview frames that stand in until the render's own arrive."""
from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from x2video.render.events import (
    FramesReady,
    RenderCancelled,
    RenderEvent,
    RenderFailed,
    RenderFinished,
    RenderStarted,
    StepDone,
    WindowStarted,
)
from x2video_app.state.preview import PreviewReady
from x2video_app.state.signals import Signal


@dataclass
class WindowRecord:
    index: int
    level: int
    mode: str
    frames: list[int]
    seconds: float | None = None


@dataclass
class RenderState:
    """What the viewer, timeline, progress bars and charts show about the current render.

    `apply(event)` is the only mutator; `changed` fires after each event with the event.
    Frames are kept as float16 linear RGB (H, W, 3) to halve memory on long shots. `frames` holds
    only what the render made (export and references read it); `preview` holds the formula's frames
    (`PreviewReady`) of the frames the render has not delivered yet, for the viewer and timeline.
    Per-frame tiers (formula, residual) record their frames at level 0.
    """

    frames: dict[int, np.ndarray] = field(default_factory=dict)
    preview: dict[int, np.ndarray] = field(default_factory=dict)
    levels: dict[int, int] = field(default_factory=dict)
    keyframes: set[int] = field(default_factory=set)
    level_order: list[int] = field(default_factory=list)
    windows: dict[int, WindowRecord] = field(default_factory=dict)
    windows_per_level: dict[int, int] = field(default_factory=dict)
    windows_done: Counter = field(default_factory=Counter)  # level -> windows finished
    num_frames: int = 0
    num_windows: int = 0
    steps_per_window: int = 0
    steps_done: int = 0
    in_flight: list[int] = field(default_factory=list)
    status: str = "idle"  # idle | running | finished | cancelled | failed
    error: str = ""
    tier: str = ""  # what renders (RenderStarted.tier): formula, residual or diffusion; "" before it says
    reason: str = ""  # why that tier (RenderStarted.reason)
    #: the tier renders every frame on its own in one pass (RenderStarted.per_frame: formula, residual): no windows
    #: or levels, progress in frames
    per_frame: bool = False
    started_at: float = 0.0
    first_frame_at: float | None = None
    first_keyframe_at: float | None = None  # the render's first frame (a keyframe in the recursive scheme)
    finished_at: float | None = None
    #: frame -> the `FramesReady.mode` it arrived with: the tier that edited it over the base ("formula",
    #: "formula+residual"), "base" (the base unchanged), a per-frame tier's name, or a sampler window's mode
    modes: dict[int, str] = field(default_factory=dict)
    #: the render keeps the shot's path-traced frames as its base (`x2video.base.plan.uses_base`), and which they are
    base: bool = False
    path_traced: frozenset[int] = frozenset()
    #: the frames of a render over the base in the input's units (float32), exactly as the base stage made them
    #: (float64 events): `frames` keeps float16 for the viewer, which would round the base's pixels; export writes these
    exact: dict[int, np.ndarray] = field(default_factory=dict)
    irradiance_scale: float = 1.0  # the shot's (`ShotInfo.irradiance_scale`): model exposure -> input units
    #: order in which frames arrived, with their mode: [(t, level, mode)], mode "preview" for the formula's
    #: preview (level 0) — tests and the demo read it
    arrivals: list[tuple[int, int, str]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.changed = Signal("render_changed")

    # -- lifecycle -------------------------------------------------------------
    def begin(self, steps_per_window: int, windows_per_level: dict[int, int] | None = None, keep_frames: bool = False,
              path_traced: tuple[int, ...] | None = None, irradiance_scale: float = 1.0) -> None:
        """Reset for a new render (called on the GUI thread when Render is pressed). `path_traced`: the shot's frames
        the render keeps as its base (`x2video_app.state.frame_sources.path_traced_frames`); None or (): no base."""
        if not keep_frames:
            self.clear_frames()
        self.base, self.path_traced = bool(path_traced), frozenset(path_traced or ())
        self.irradiance_scale = float(irradiance_scale)
        self.arrivals.clear()
        self.windows.clear()
        self.windows_per_level = dict(windows_per_level or {})
        self.windows_done = Counter()
        self.level_order = []
        self.steps_per_window = steps_per_window
        self.steps_done = 0
        self.in_flight = []
        self.status = "running"
        self.error = self.tier = self.reason = ""
        self.per_frame = False
        self.started_at = time.perf_counter()
        self.first_frame_at = self.first_keyframe_at = self.finished_at = None
        self.changed.emit(None)

    def clear_frames(self) -> None:
        self.frames.clear()
        self.preview.clear()
        self.levels.clear()
        self.keyframes.clear()
        self.modes.clear()
        self.exact.clear()

    def image(self, t: int) -> np.ndarray | None:
        """What the viewer shows for frame `t`: the render's frame, else its preview, else None."""
        img = self.frames.get(t)
        return self.preview.get(t) if img is None else img

    @property
    def top_level(self) -> int:
        return max(self.level_order) if self.level_order else (max(self.levels.values()) if self.levels else 1)

    def apply(self, ev: RenderEvent) -> None:
        now = time.perf_counter()
        if isinstance(ev, PreviewReady):
            for t, img in ev.frames.items():
                if t in self.frames:  # the render's frame came first: it stays
                    continue
                self.preview[t] = np.asarray(img, dtype=np.float16)
                self.arrivals.append((t, 0, "preview"))
            if self.first_frame_at is None and self.preview:
                self.first_frame_at = now
        elif isinstance(ev, RenderStarted):
            self.num_frames, self.num_windows, self.level_order = ev.num_frames, ev.num_windows, list(ev.levels)
            self.tier, self.reason, self.per_frame = ev.tier, ev.reason, ev.per_frame
            if self.per_frame:  # the window plan the controller guessed does not apply
                self.windows_per_level, self.level_order = {}, [0]
        elif isinstance(ev, WindowStarted):
            self.windows[ev.index] = WindowRecord(ev.index, ev.level, ev.mode, list(ev.frames))
            self.in_flight = list(ev.frames)
        elif isinstance(ev, StepDone):
            self.steps_done += 1
            self.steps_per_window = ev.steps
        elif isinstance(ev, FramesReady):
            rec = self.windows.get(ev.window)
            if rec is not None:
                rec.seconds = ev.seconds
            if ev.window_done:
                self.windows_done[ev.level] += 1
            level = 0 if self.per_frame else ev.level
            for t, img in ev.frames.items():
                self.frames[t] = np.asarray(img, dtype=np.float16)
                if self.base and np.asarray(img).dtype == np.float64:  # the base stage's frame: kept exact for export
                    self.exact[t] = (np.asarray(img) / self.irradiance_scale).astype(np.float32)  # as OutputUnits.scene
                else:
                    self.exact.pop(t, None)
                self.preview.pop(t, None)
                self.levels[t] = level
                self.modes[t] = ev.mode
                if ev.mode == "key" and level == self.top_level and not self.per_frame:
                    self.keyframes.add(t)
                else:  # the seam pass makes keyframes again in interpolation windows
                    self.keyframes.discard(t)
                self.arrivals.append((t, level, ev.mode))
            if self.first_frame_at is None:
                self.first_frame_at = now
            if self.first_keyframe_at is None:
                self.first_keyframe_at = now
            if ev.window_done:
                self.in_flight = []
        elif isinstance(ev, RenderFinished):
            self.status, self.finished_at, self.in_flight = "finished", now, []
        elif isinstance(ev, RenderCancelled):
            self.status, self.finished_at, self.in_flight = "cancelled", now, []
        elif isinstance(ev, RenderFailed):
            self.status, self.error, self.finished_at, self.in_flight = "failed", ev.error, now, []
        self.changed.emit(ev)

    def fail(self, message: str) -> None:
        """The worker raised instead of emitting RenderFailed (e.g. out of memory)."""
        self.apply(RenderFailed(error=message))

    # -- derived figures -------------------------------------------------------
    def level_progress(self) -> list[tuple[int, int, int]]:
        """[(level, windows finished, windows planned)] in run order; planned is 0 when unknown.
        Per-frame tiers: [(0, frames finished, frames planned)]."""
        if self.per_frame:
            return [(0, len(self.frames), self.num_frames)]
        levels = self.level_order or sorted(set(self.windows_done), reverse=True)
        return [(lv, self.windows_done.get(lv, 0), self.windows_per_level.get(lv, 0)) for lv in levels]

    def eta_seconds(self) -> float | None:
        """Remaining seconds, from the mean time per denoising step (per frame for per-frame tiers) so far
        (None before the first)."""
        if self.status == "running" and self.per_frame and self.frames and self.num_frames:
            elapsed = time.perf_counter() - self.started_at
            return max(0.0, elapsed / len(self.frames) * (self.num_frames - len(self.frames)))
        if self.status != "running" or self.steps_done == 0 or not self.num_windows or not self.steps_per_window:
            return None
        elapsed = time.perf_counter() - self.started_at
        total = self.num_windows * self.steps_per_window
        return max(0.0, elapsed / self.steps_done * (total - self.steps_done))

    def time_to_first_keyframe(self) -> float | None:
        return None if self.first_keyframe_at is None else self.first_keyframe_at - self.started_at
