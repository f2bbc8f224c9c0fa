"""`Renderer`: renders a shot with the tier it needs and streams finished frames as typed events.

One entry point for every tier (`x2video.tiers.base`): `render` decides the tier (`tiers.decide`: the one
forced by `RenderSettings.quality`, or auto's choice), builds the frames' conditioning
(`x2video.conditioning`) and lets the tier emit its frames; tier 0 needs no model (`Renderer(None)`). The
diffusion tier encodes each frame's conditioning once through a content-keyed cache that outlives the render (a
prompt-only re-render re-encodes nothing; `retain=False` for one-off renders drops each frame's entries after
its last window). No global state: one Renderer per thread, or one shared Renderer driven from one thread at a
time. docs/ARCHITECTURE.md shows where it sits.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import torch

from x2video.base import stage as base_stage
from x2video.base.fill import BaseFrames
from x2video.base.keyframes import keyframed, reference_keyframes
from x2video.base.plan import base_plan, fill_choice, make_plan
from x2video.conditioning.cache import CacheStats, ConditioningCache, conditioning_key
from x2video.conditioning.edited import frame_conditioning, resolve_reference
from x2video.conditioning.network import NetworkConditioning
from x2video.model.api import WindowInputs
from x2video.render.events import (
    Cancelled,
    CancelToken,
    EventCallback,
    FramesReady,
    RenderCancelled,
    RenderEvent,
    RenderFailed,
    RenderFinished,
)
from x2video.render.settings import RenderSettings, frame_range, resolve
from x2video.render.timing import NoTimes, StageTimes
from x2video.sampling.planner import Window
from x2video.sampling.samplers import alphas_cumprod
from x2video.shot import Shot
from x2video.tiers import registry
from x2video.tiers.base import RenderJob, RenderPlan, TierChoice
from x2video.tiers.diffusion import DiffusionTier, diffusion_windows, given_keyframes, reference_frame
from x2video.tiers.encoder import Encoder

if TYPE_CHECKING:
    from x2video.base.stage import GeneratedOver
    from x2video.edits.model import Edits
    from x2video.model.api import RenderModel

log = logging.getLogger(__name__)

_NO_TIMES = NoTimes()

class Renderer:
    """Renders shots with `model` (None: only tiers that need no model, e.g. the formula); see the module docstring."""

    def __init__(self, model: RenderModel | None, *, cache: ConditioningCache | None = None, retain: bool = True) -> None:
        self.model = model
        self.cache = cache if cache is not None else ConditioningCache()
        #: True: each frame's conditioning latents and detail stay in `cache` after the render, so a re-render
        #: re-encodes nothing (the editor). False: they leave the cache after the last window that reads them
        #: (the CLI and farm workers, which render once): a 1,000-frame shot at 320x224 then holds the frames still
        #: ahead instead of 0.8 GB (issue 31).
        self.retain = retain
        #: wall seconds spent encoding conditioning (channel latents) in the last render; 0 when
        #: the cache held every frame (the editor's re-render). Benchmarks split time with it.
        self.encode_seconds = 0.0
        #: most reference latents held at once during the last render (they are dropped after their last use)
        self.peak_latents = 0
        #: set to a `StageTimes` to have each render split its wall time into stages (read, encode, unet, decode,
        #: detail, residual, write; bench/render.py); None (the default) times nothing
        self.timing: StageTimes | None = None
        #: what ran the UNet, VAE decoder and channel encoder in the last diffusion render (`RenderSettings.engine`)
        self.engine = "torch"
        #: the tier the last render ran, and why
        self.last_tier: TierChoice | None = None
        self._preparing: CancelToken | None = None  # the token of a `prepare` in progress; a render cancels it
        #: a retaining Renderer's base frames (`x2video.base.fill.BaseFrames`) of the shot it last rendered over its
        #: base, with that shot and its keyframes setting: the live preview renders one frame per slider move, and a
        #: frame between keyframes is then filled once, not on every move (the fill does not depend on the edits)
        self._bases: tuple[Shot, str | None, BaseFrames] | None = None
        if model is not None:
            ours, theirs = alphas_cumprod(), model.alphas_cumprod().to(torch.float64).cpu()
            if ours.shape != theirs.shape or not torch.allclose(ours, theirs, atol=1e-6):
                raise ValueError(
                    "the model's noise schedule is not the SD 2.1 zero-terminal-SNR schedule the samplers use "
                    f"({theirs.shape[0]} steps, alpha_cumprod[0]={float(theirs[0]):.6f})"
                )

    @property
    def clock(self) -> StageTimes | NoTimes:
        """Where this Renderer's stages are timed: `timing`, or nothing."""
        return self.timing if self.timing is not None else _NO_TIMES

    # -- for the editor, the farm and tests ----------------------------------------
    def prepare(self, shot: Shot, settings: RenderSettings, edits: Edits | None = None, cancel: CancelToken | None = None, *,
                base_dir: str | Path | None = None) -> int:
        """Encode ahead what a diffusion render of `shot` would encode first, into this Renderer's cache, and
        build the engine's graphs (`warm_engine`); returns the frames encoded. Tiers 0 and 1 encode nothing, so there is
        nothing to prepare for them. For a worker
        thread: a `render` started meanwhile cancels it and reuses what it finished."""
        token = cancel if cancel is not None else CancelToken()
        self._preparing = token
        try:
            return self._prepare(shot, settings, edits, token)
        finally:
            if self._preparing is token:
                self._preparing = None

    def _prepare(self, shot: Shot, settings: RenderSettings, edits: Edits | None, cancel: CancelToken) -> int:
        """See the module docstring; returns how many frames were encoded now (0 when the cache had them all,
        the tier needs no encoding, or `cancel` was set before any). The conditioning is the diffusion tier's own
        (`NetworkConditioning`: padded, or at the working size for large frames)."""
        model = self.model
        choice = self.choose_tier(shot, edits, settings)
        given = given_keyframes(shot, settings, frame_range(shot, settings))
        if model is None or (choice.tier != DiffusionTier.name and not given):
            return 0
        t0 = time.perf_counter()
        net = NetworkConditioning.for_model(shot.size, frame_conditioning(shot, edits), model.downsample, settings.working_pixels)
        settings = resolve(settings, model)
        self.engine = model.set_engine(settings.engine)
        windows = diffusion_windows(frame_range(shot, settings), settings, None if given else reference_frame(edits), given)
        text = model.encode_prompts([""]) if model.text_encoder is not None else None  # loads the text encoder
        encoder = Encoder(model, self.cache, self.clock)
        model_key = model.content_key()
        encoded = ready = 0
        with torch.inference_mode():
            for index, window in enumerate(windows):
                if cancel is not None and cancel.cancelled:
                    break
                ready += 1
                conds = [net.frame(f) for f in window.frames]
                keys = [conditioning_key(c, model_key) for c in conds]
                before = self.cache.stats().entries
                cond = encoder.encode(conds, keys)  # (n, C_cond, h, w)
                if settings.detail:
                    gen = list(window.generate_positions)
                    encoder.detail([conds[p] for p in gen], [keys[p] for p in gen], cond[gen])
                encoded += max(0, self.cache.stats().entries - before)
                if index == 0 and text is not None:  # the first keyframe window is encoded: now every graph the render runs
                    warm_engine(self, windows, settings, (cond.shape[-2], cond.shape[-1]), text, cancel)
        log.info("prepared %d of %d windows (%d frames encoded now, engine %s) in %.2f s", ready, len(windows),
                 encoded, self.engine, time.perf_counter() - t0)
        return encoded

    def cache_stats(self) -> CacheStats:
        return self.cache.stats()

    def plan(self, shot: Shot, settings: RenderSettings, ref_frame: int | None = None) -> list[Window]:
        """The windows a diffusion render of `shot` with `settings` runs (shot frame indices), anchored at `ref_frame`, or
        around the keyframes fill 'diffusion' gives it (`given_keyframes`)."""
        frames = frame_range(shot, settings)
        return diffusion_windows(frames, settings, ref_frame, given_keyframes(shot, settings, frames))

    def plan_render(self, shot: Shot, edits: Edits | None, settings: RenderSettings) -> RenderPlan:
        """What a render of `shot` with `edits` and `settings` runs with this model (`tiers.plan_render`, pure)."""
        fill = fill_choice(shot, edits, settings)
        if fill is not None:
            return registry.get(fill.tier).plan(shot, edits, settings, self.model, fill, frame_range(shot, settings))
        return base_plan(shot, edits, settings) or registry.plan_render(shot, edits, settings, self.model)

    def choose_tier(self, shot: Shot, edits: Edits | None, settings: RenderSettings) -> TierChoice:
        """The tier a render of `shot` with `edits` (or None) and `settings` runs with this model, and why
        (`x2video.tiers.registry.decide`); read from the edits' structure, so it costs nothing."""
        return registry.decide(settings.quality, shot, edits, self.model, settings.base)

    def render_plan(self, shot: Shot, edits: Edits | None, settings: RenderSettings, *, base_dir: str | Path | None = None) -> list[Window]:
        """The windows a windowed (diffusion) render of `shot` with `edits` and `settings` runs (anchored at the user's
        reference frame where the edits have one); `render_windows` takes their indices. ValueError when the render's
        tier renders frame by frame (it has no windows). `base_dir` is accepted for the old signature."""
        p = self.plan_render(shot, edits, settings)
        if p.per_frame:
            raise ValueError(f"this render runs tier {p.tier!r} ({p.reason}), which has no windows")
        return list(p.windows)

    def _job(self, shot: Shot, edits: Edits | None, settings: RenderSettings, choice: TierChoice, reads_reference: bool,
             base_dir: str | Path | None) -> RenderJob:
        reference = None
        if edits is not None and reads_reference:
            reference = resolve_reference(shot, edits, base_dir)
        return RenderJob(shot=shot, edits=edits, settings=settings, choice=choice, model=self.model,
                         conditioning=self.clock.wrap("read", frame_conditioning(shot, edits)), frames=frame_range(shot, settings),
                         cache=self.cache, retain=self.retain, clock=self.clock, base_dir=base_dir, reference=reference)

    def _report(self, stats: dict) -> None:
        """Keep what the tier reported of the render (`RenderJob.stats`)."""
        self.encode_seconds = stats.get("encode_seconds", 0.0)
        self.peak_latents = stats.get("peak_latents", self.peak_latents)
        self.engine = stats.get("engine", self.engine)

    # -- the render ------------------------------------------------------------------
    def render(
        self,
        shot: Shot,
        edits: Edits | None,
        settings: RenderSettings,
        on_event: EventCallback | None = None,
        cancel: CancelToken | None = None,
        *,
        base_dir: str | Path | None = None,
        generated: GeneratedOver = "difference",
    ) -> None:
        """Render `shot` with `edits` (an `x2video.edits.Edits`, or None for none).

        Emits RenderStarted, then the tier's events (per window WindowStarted, StepDone per step, FramesReady;
        per-frame tiers FramesReady only); then RenderFinished. Cancelling (between steps or batches of frames)
        emits RenderCancelled with the finished frames and returns. Any error emits RenderFailed and is re-raised.
        `base_dir` resolves relative paths of a reference image in the edits (the project file's folder). `generated`:
        how a generating tier's frame goes over the shot's base (`x2video.base.stage.GeneratedOver`; bench.edits
        measures the two).
        """
        t0 = time.perf_counter()
        preparing = self._preparing
        if preparing is not None:  # the render computes what is left; two would share the cores
            preparing.cancel()
        if self.timing is not None:
            self.timing.reset()
        emit: Callable[[RenderEvent], None] = on_event if on_event is not None else (lambda e: None)
        if self.timing is not None:
            emit = self._timed_emit(emit, self.timing)
        done: set[int] = set()  # frames delivered so far
        self.encode_seconds = 0.0
        try:
            try:
                settings.validate()  # every field, before any tier is chosen (a field changed in place since it was made, too)
                keys = reference_keyframes(shot, settings)  # fill 'diffusion': the keyframes the tier reads as references
                source, shot = shot, keyframed(shot, settings)  # the shot's path-traced frames: the base (x2video.base.stage)
                stats: dict = {}  # what the tier reports back
                plan = make_plan(shot, edits, settings, self.model, frame_range(shot, settings), keys, cache=self.cache,
                                 retain=self.retain, clock=self.clock, stats=stats, base_dir=base_dir,
                                 bases=self._base_frames(source, shot, settings) if self.retain else None)
                choice = self.last_tier = plan.job.choice
                log.info("quality %s: tier %s (%s)", settings.quality, choice.tier, choice.reason)
                try:
                    base_stage.render(plan, emit, cancel, done, generated=generated)
                finally:
                    self._report(stats)
                emit(RenderFinished(num_frames=len(done), seconds=time.perf_counter() - t0))
            except Cancelled:
                log.info("render cancelled after %d frames", len(done))
                emit(RenderCancelled(frames_done=sorted(done)))
            except Exception as exc:
                emit(RenderFailed(error=f"{type(exc).__name__}: {exc}"))
                raise
        finally:
            if self.timing is not None:
                self.timing.total = time.perf_counter() - t0

    def _base_frames(self, source: Shot, shot: Shot, settings: RenderSettings) -> BaseFrames:
        """The base frames of `shot` (`source` keyframed by `settings`) this Renderer keeps across renders (`_bases`):
        the same object while `source` and the keyframes setting stay; making one computes nothing."""
        held = self._bases
        if held is None or held[0] is not source or held[1] != settings.keyframes:
            held = self._bases = (source, settings.keyframes, BaseFrames(shot))
        return held[2]

    @staticmethod
    def _timed_emit(emit: Callable[[RenderEvent], None], timing: StageTimes) -> Callable[[RenderEvent], None]:
        """`emit` with the `FramesReady` callbacks timed as stage 'write' (a sink writing the frames)."""

        def timed(event: RenderEvent) -> None:
            if isinstance(event, FramesReady):
                with timing.stage("write"):
                    emit(event)
            else:
                emit(event)

        return timed

    def render_windows(self, shot: Shot, edits: Edits | None, settings: RenderSettings, indices: Sequence[int], refs: dict[int, torch.Tensor],
                       on_event: EventCallback | None = None, cancel: CancelToken | None = None, *,
                       base_dir: str | Path | None = None) -> dict[int, dict[int, torch.Tensor]]:
        """Render only the windows `indices` (of `render_plan`, in plan order) of a diffusion render, given `refs`: frame ->
        (4, h, w) RGB latent of every reference frame they read and do not make themselves (the latents an earlier
        call returned). Returns, per window, its generated frames' RGB latents; emits WindowStarted, StepDone and
        FramesReady for its frames (not RenderStarted/RenderFinished: this is part of a render).

        The windows of one recursive level read only frames of the levels above, so a farm runs them in parallel
        (`x2video.farm`). `render` runs each window through the same steps (the noise is seeded per frame or per
        window, the conditioning per frame), so the frames equal a single `render`'s."""
        emit: Callable[[RenderEvent], None] = on_event if on_event is not None else (lambda e: None)
        shot = keyframed(shot, settings)
        choice = fill_choice(shot, edits, settings) or self.choose_tier(shot, edits, settings)
        tier = registry.get(choice.tier)
        if not isinstance(tier, DiffusionTier):
            raise ValueError(f"this render runs tier {choice.tier!r} ({choice.reason}), which has no windows")
        job = self._job(shot, edits, settings, choice, True, base_dir)
        try:
            return tier.render_windows(job, indices, refs, emit, cancel)
        finally:
            self._report(job.stats)


def warm_engine(renderer: Renderer, windows: Sequence[Window], settings: RenderSettings, latent_size: tuple[int, int],
                text: torch.Tensor | None = None, cancel: CancelToken | None = None) -> int:
    """Build (export or read from the disk cache, compile) and run once on zeros the engine's graph of every UNet
    variant `windows` use, in plan order and as many as the engine keeps at once (`engine.UNET_GRAPHS`: a long
    shot's later levels come back from the blob cache when reached), and the decoder's, so no render call pays
    for them; nothing for PyTorch. Returns the variants built. `settings` must be validated
    (`x2video.render.settings.resolve`: the sampler resolved)."""
    model = renderer.model
    if model is None or renderer.engine == "torch":
        return 0
    from x2video.model.engine import UNET_GRAPHS, unet_variant

    lcm = settings.sampler == "lcm"
    h, w = latent_size
    if text is None:
        text = model.encode_prompts([""])  # (1, L, D)
    seen: set[tuple] = set()
    with torch.inference_mode():
        model.decode(torch.zeros(1, model.latent_channels, h, w, device=model.device, dtype=model.dtype))
        for window in windows:
            n = len(window.frames)
            variant = unet_variant(window.mode, window.level, window.ref_positions, n, model.config.hybrid.interp_levels)
            if variant in seen:
                continue
            if len(seen) == UNET_GRAPHS or (cancel is not None and cancel.cancelled):
                break
            seen.add(variant)
            z = torch.zeros(n, model.latent_channels, h, w, device=model.device, dtype=model.dtype)  # (n, 4, h, w)
            inputs = WindowInputs(cond=torch.zeros(n, model.cond_channels, h, w, device=model.device, dtype=model.dtype), ref=z,
                                  ref_positions=window.ref_positions, mode=window.mode, level=window.level, text_global=text,
                                  text_local=text.new_zeros((0, *text.shape[1:])),
                                  local_masks=torch.zeros(n, 0, h * model.downsample, w * model.downsample))
            model.predict_v(z, torch.tensor(999), inputs, lcm=lcm)
    return len(seen)
