"""`Tier`: one way of rendering frames (docs/ARCHITECTURE.md, "Adding a tier"), and the registry of them.

A tier is one class: its `name` (what `RenderSettings.quality` forces), whether it needs a model
(`needs_model`), the channels it reads (`channels`), the plan of a render it runs (`plan`: windows and steps,
pure) and `render`, which turns a `RenderJob` into the same typed events every tier emits (RenderStarted, then
FramesReady as frames finish; the `Renderer` adds RenderFinished, RenderCancelled or RenderFailed). Defining a
subclass with a `name` registers it (`TIERS`); `x2video.tiers.registry` decides which one a render runs.

Per-frame tiers (`PerFrameTier`: every frame on its own, no windows) only say how a batch of frames is made
(`frames`); the loop that orders, batches, cancels and emits is theirs in common.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, ClassVar, Sequence

import numpy as np

from x2video.channels import INTRINSIC
from x2video.conditioning.frame import FrameConditioning
from x2video.render.events import Cancelled, CancelToken, FramesReady, RenderEvent, RenderStarted
from x2video.render.settings import RenderSettings
from x2video.render.timing import NoTimes, StageTimes
from x2video.sampling.planner import Window

if TYPE_CHECKING:
    from x2video.conditioning.cache import ConditioningCache
    from x2video.edits.model import Edits
    from x2video.model.api import RenderModel
    from x2video.shot import Shot

#: name -> tier class, in the order they were defined (the built-in ones in cost order: formula, residual, diffusion)
TIERS: dict[str, type[Tier]] = {}

Emit = Callable[[RenderEvent], None]


@dataclass(frozen=True)
class TierChoice:
    """What a render runs: `tier` for the frames, and `regions` True when tier 2 runs only inside
    the generated regions of frames that otherwise have every channel (composited over `base`)."""

    tier: str
    reason: str
    base: str = ""
    regions: bool = False


@dataclass(frozen=True)
class RenderPlan:
    """What a render will run, decided before it starts (`x2video.tiers.registry.plan_render`, a pure function):
    the editor sizes its progress bars from it and the farm splits a shot by it."""

    tier: str
    reason: str
    frames: tuple[int, int]  # [start, stop) of the shot
    per_frame: bool  # every frame on its own (no windows: progress in frames, a farm splits into frame chunks)
    windows: tuple[Window, ...] = ()  # the windows in the order they run (shot frame indices); () for per-frame tiers
    sampler: str | None = None  # the resolved sampler ('ddim', 'lcm') of a windowed tier
    steps: int = 1  # denoising steps per window (1 per frame for per-frame tiers)

    @property
    def num_frames(self) -> int:
        return self.frames[1] - self.frames[0]

    def windows_per_level(self) -> dict[int, int]:
        """level -> windows of that level (empty for per-frame tiers)."""
        out: dict[int, int] = {}
        for w in self.windows:
            out[w.level] = out.get(w.level, 0) + 1
        return out


@dataclass
class RenderJob:
    """One render as a tier sees it: the shot, its edits and settings, the tier's choice, and the Renderer's model, cache
    and clock. `conditioning(t)`: frame t's edited conditioning (timed as stage 'read'); `reference`: the user's
    reference (frame, linear image) for tiers that read one, else None."""

    shot: Shot
    edits: Edits | None
    settings: RenderSettings
    choice: TierChoice
    model: RenderModel | None
    conditioning: Callable[[int], FrameConditioning]
    frames: tuple[int, int]
    cache: ConditioningCache
    retain: bool = True
    clock: StageTimes | NoTimes = field(default_factory=NoTimes)
    base_dir: str | Path | None = None
    reference: tuple[int, np.ndarray] | None = None
    #: what the tier reports back to the Renderer: 'engine' (what ran the network), 'encode_seconds', 'peak_latents'
    stats: dict = field(default_factory=dict)


class Tier:
    """One way of rendering a shot's frames; see the module docstring. Subclasses set the class attributes."""

    #: what `RenderSettings.quality` calls it (and `RenderStarted.tier` says)
    name: ClassVar[str]
    #: False: renders without a model (`Renderer(None)` can run it)
    needs_model: ClassVar[bool] = True
    #: the intrinsic channels it reads (the others may be missing without changing its frames)
    channels: ClassVar[tuple[str, ...]] = INTRINSIC
    #: every frame on its own in one pass: no windows, progress in frames, a farm splits it into frame chunks
    per_frame: ClassVar[bool] = False
    #: reads the user's reference frame (`RenderJob.reference` is resolved only for such tiers)
    reads_reference: ClassVar[bool] = False
    #: a render of any part of a frame range gives its frames the same bytes as a render of the whole range (no batch
    #: or window touches another frame's pixels), so a resumed render may render only the frames it lacks
    exact_in_part: ClassVar[bool] = False
    #: makes what the channels do not say (a dropped channel, a masked-out region, a local prompt, a reference's look):
    #: its frames are the ones the editor's Compare offers as the generated version
    generative: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if "name" in cls.__dict__:
            TIERS[cls.name] = cls

    def available(self, model: RenderModel | None) -> str | None:
        """None when this tier can render with `model` (None: no model), else why not (a ValueError's message)."""
        if self.needs_model and model is None:
            return f"quality {self.name!r} needs a model (load weights, or render with quality 'formula')"
        return None

    def with_preset(self, settings: RenderSettings, model: RenderModel | None) -> RenderSettings:
        """`settings` as this tier runs them on `model`: `settings.preset` resolved into the knobs it sets (a tier that
        reads no preset: `settings` as given). Pure, unvalidated (the speed/accuracy chart marks a render by it)."""
        return settings

    def working_size(self, size: tuple[int, int], settings: RenderSettings, model: RenderModel | None) -> tuple[int, int] | None:
        """(H, W) this tier runs its network at for frames of `size` (H, W) on `model`, or None: at full size (or no network)."""
        return None

    def plan(self, shot: Shot, edits: Edits | None, settings: RenderSettings, model: RenderModel | None, choice: TierChoice,
             frames: tuple[int, int]) -> RenderPlan:
        """What a render of frames [start, stop) runs with this tier (pure: no pixels read, nothing encoded)."""
        return RenderPlan(choice.tier, choice.reason, frames, per_frame=True)

    def render(self, job: RenderJob, emit: Emit, cancel: CancelToken | None, done: set[int]) -> None:
        """Emit RenderStarted and the job's frames as FramesReady events (adding each frame delivered to `done`);
        raise `Cancelled` when `cancel` is set."""
        raise NotImplementedError


def coarse_to_fine(start: int, stop: int) -> list[int]:
    """Frames of [start, stop) in the order a timeline fills best: ends first, then halves recursively."""
    order, seen = [], set()
    span = 1
    while span < stop - start:
        span *= 2
    while span >= 1:
        for f in range(start, stop, span):
            if f not in seen:
                seen.add(f)
                order.append(f)
        span //= 2
    if stop - 1 not in seen:
        order.insert(1, stop - 1)
    return order


class PerFrameTier(Tier):
    """A tier that makes every frame on its own: subclasses say how a batch of frames is made (`frames`)."""

    per_frame = True
    #: frames per event after the first (which comes alone, so it shows as soon as one pass allows)
    batch: ClassVar[int] = 4
    #: renders an edit's glossy change (roughness, metallic, normal), which no rebuild from passes makes: over the shot's
    #: base its difference (`glossy_frames`) replaces tier 0's there (`x2video.base.difference.edited_frame`)
    glossy: ClassVar[bool] = False

    def frames(self, job: RenderJob, conds: Sequence[FrameConditioning]) -> list[np.ndarray]:
        """(H, W, 3) linear RGB float32 frames of `conds` (frames' edited conditioning, in order)."""
        raise NotImplementedError

    def base_frames(self, job: RenderJob, conds: Sequence[FrameConditioning]) -> list[np.ndarray]:
        """The frames this tier lays under a regional diffusion render (`TierChoice.base`): its own by default."""
        return self.frames(job, conds)

    def glossy_frames(self, job: RenderJob, edited: FrameConditioning, original: FrameConditioning,
                      wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """This tier's frames of (`edited`, `original`), whose difference renders an edit's glossy change over the shot's
        base (`glossy` tiers), needed inside the (H, W) bool mask `wanted` (anything outside it)."""
        r_e, r_o = self.frames(job, [edited, original])
        return r_e, r_o

    def learned_difference(self, job: RenderJob) -> bool:
        """Whether `glossy_frames` are a difference net's: its residual over the formula (R - F), which the base stage adds
        to tier 0's rebuild wherever a material changed (`x2video.base.stage.edited_frame`), instead of whole frames."""
        return False

    def begin(self, job: RenderJob) -> None:
        """Called once before the first frame (a log line, say)."""

    def render(self, job: RenderJob, emit: Emit, cancel: CancelToken | None, done: set[int]) -> None:
        """Every frame on its own, coarse to fine (the timeline fills evenly), a few per event; the first frame alone."""
        order = coarse_to_fine(*job.frames)
        emit(RenderStarted(num_frames=len(order), num_windows=0, levels=[0], tier=job.choice.tier, reason=job.choice.reason, per_frame=True))
        self.begin(job)
        for index, i in enumerate([0, *range(1, len(order), self.batch)]):
            if cancel is not None and cancel.cancelled:
                raise Cancelled(f"cancelled after {len(done)} frames")
            tw = time.perf_counter()
            fs = order[i:i + self.batch] if i else order[:1]
            images = self.frames(job, [job.conditioning(f) for f in fs])
            done.update(fs)
            emit(FramesReady(window=index, frames=dict(zip(fs, images)), level=0, mode=job.choice.tier, seconds=time.perf_counter() - tw))
