"""`Renderer`: runs a frame plan window by window and streams finished frames as typed events.

Paper Sec. Recursive Sampling (keyframes, then interpolation levels) and Sec. Acceleration
(reference frame, LCM-2). Per render: edits applied frame by frame, prompts encoded once,
each frame's conditioning encoded once through a content-keyed cache that outlives the
render (a prompt-only re-render re-encodes nothing; `retain=False` for one-off renders drops
each frame's entries after its last window), initial noise seeded per window, and
only the latents that later windows read as references are kept; decoded frames leave
through `FramesReady` events and are not held. No global state: one Renderer per thread,
or one shared Renderer driven from one thread at a time.
"""
from __future__ import annotations

import dataclasses
import functools
import logging
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch

from x2video.channels import INTRINSIC
from x2video.conditioning import FrameConditioning, Prompts
from x2video.model.api import RenderModel, WindowInputs
from x2video.model.residual import formula
from x2video.model.shading import shading_available
from x2video.sampling import tiers, working
from x2video.sampling.cache import CacheStats, ConditioningCache, conditioning_key
from x2video.sampling.events import (
    Cancelled,
    CancelToken,
    EventCallback,
    FramesReady,
    RenderCancelled,
    RenderEvent,
    RenderFailed,
    RenderFinished,
    RenderStarted,
    StepDone,
    WindowStarted,
)
from x2video.sampling.planner import Window, last_use, plan, shift
from x2video.sampling.samplers import Known, alphas_cumprod, mix_noise, sample_ddim, sample_lcm
from x2video.sampling.settings import RenderSettings
from x2video.sampling.timing import NoTimes, StageTimes
from x2video.shot import Shot

log = logging.getLogger(__name__)


def select_steps(settings: RenderSettings, model: RenderModel) -> RenderSettings:
    """Resolve `settings.preset` into a sampler and step count for this model.

    'fast': LCM-2 when the model has distilled (LCM) weights, else DDIM-4; 'quality': DDIM-20;
    None: the settings as given.
    """
    if settings.preset is None:
        return settings
    if settings.preset == "fast":
        sampler, steps = ("lcm", 2) if model.has_lcm else ("ddim", 4)
    elif settings.preset == "quality":
        sampler, steps = "ddim", 20
    else:
        raise ValueError(f"unknown render preset {settings.preset!r} (use 'fast' or 'quality')")
    return dataclasses.replace(settings, sampler=sampler, steps=steps)


def plain_conditioning(shot: Shot, t: int) -> FrameConditioning:
    """A frame's conditioning with no edits: the shot's channels, absent ones dropped, no masks."""
    h, w = shot.size
    channels: dict[str, np.ndarray | None] = {n: shot.channel(n, t) if shot.has(n) else None for n in INTRINSIC}
    return FrameConditioning(
        channels=channels,
        amr_mask=np.zeros((h, w), np.float32),
        local_masks=np.zeros((0, h, w), np.float32),
        frame_index=t,
    )


def pad_amounts(size: tuple[int, int], factor: int) -> tuple[int, int]:
    """(rows, columns) to add at the bottom and right so that (H, W) become multiples of `factor`."""
    h, w = size
    return (-h) % factor, (-w) % factor


def pad_image(a: np.ndarray, ph: int, pw: int) -> np.ndarray:
    """Reflect-pad the first two axes (H, W, ...) of `a` by `ph` rows at the bottom and `pw` columns at
    the right (edge where an axis has one pixel); never a resize."""
    if not ph and not pw:
        return a
    widths = [(0, ph), (0, pw)] + [(0, 0)] * (a.ndim - 2)
    mode = "reflect" if min(a.shape[:2]) > 1 else "edge"
    return np.pad(a, widths, mode=mode)


def pad_conditioning(cond: FrameConditioning, ph: int, pw: int) -> FrameConditioning:
    """`cond` reflect-padded at the bottom/right (channels, A|M|R mask and local masks alike)."""
    if not ph and not pw:
        return cond
    masks = np.asarray(cond.local_masks)
    return dataclasses.replace(
        cond,
        channels={k: None if v is None else pad_image(np.asarray(v), ph, pw) for k, v in cond.channels.items()},
        amr_mask=pad_image(np.asarray(cond.amr_mask), ph, pw),
        local_masks=np.stack([pad_image(m, ph, pw) for m in masks]) if masks.shape[0] else np.zeros((0, masks.shape[1] + ph, masks.shape[2] + pw), np.float32),
    )


def window_seed(seed: int, window: Window) -> int:
    """Seed of one window's initial noise: depends on the user seed and the window's frames and level only."""
    return int(np.random.SeedSequence([seed, window.level, *window.frames]).generate_state(1, np.uint64)[0] >> 1)


def _seeded(*entropy: int) -> torch.Generator:
    return torch.Generator(device="cpu").manual_seed(int(np.random.SeedSequence(list(entropy)).generate_state(1, np.uint64)[0] >> 1))


def frame_noise(seed: int, frames: Sequence[int], shape: tuple[int, ...], shared: float = 0.0, draw: int = 0) -> torch.Tensor:
    """(len(frames), *shape) CPU float32 noise, one draw per shot frame (`RenderSettings.noise` =
    'frame'): frame f's noise depends only on the seed, f, `draw` (0: the initial noise; i: what LCM
    adds back after step i) and `shared`, the fraction of variance every frame shares:
    sqrt(shared) e + sqrt(1 - shared) e_f with e and e_f independent N(0, I)."""
    x = torch.stack([torch.randn(*shape, generator=_seeded(seed, 1, draw, f)) for f in frames])
    return mix_noise(x, torch.randn(*shape, generator=_seeded(seed, 2, draw)), shared) if shared > 0.0 else x


def inferred_region(cond: FrameConditioning, size: tuple[int, int]) -> torch.Tensor:
    """(h, w) weights in [0, 1] of where a frame's lighting must be inferred, at latent size (h, w):
    everywhere without albedo or irradiance (no classical shading), else the A|M|R mask, area-averaged."""
    if not shading_available(cond.channels):
        return torch.ones(size)
    m = torch.from_numpy(np.asarray(cond.amr_mask, np.float32))[None, None]  # (1, 1, H, W)
    return torch.nn.functional.adaptive_avg_pool2d(m, size)[0, 0]


def region_mean(z: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(..., 4) weighted mean per channel of latents z (..., 4, h, w) over region weights w (..., h, w)."""
    w = w.to(z.device, torch.float32)[..., None, :, :]
    return (z.float() * w).sum(dim=(-2, -1)) / w.sum(dim=(-2, -1))


def anchor_positions(window: Window, strength: float,
                     regions: Sequence[torch.Tensor]) -> tuple[int, int, list[int]] | None:
    """Where `mean_anchor` acts in a window: (p0, p1, gen), the positions of its two references and of
    the generated frames with an inferred region (`regions[p]`, (h, w) weights); None unless the window
    interpolates between two references, strength > 0 and some frame of it has such a region (less
    than one latent pixel counts as none)."""
    if strength <= 0 or window.mode != "interp" or len(window.refs) != 2:
        return None
    p0, p1 = (window.frames.index(f) for f in window.refs)
    if min(float(regions[p0].sum()), float(regions[p1].sum())) < 1.0:
        return None
    gen = [p for p in window.generate_positions if float(regions[p].sum()) >= 1.0]
    return (p0, p1, gen) if gen else None


def mean_anchor(window: Window, strength: float, ref: torch.Tensor, offset: torch.Tensor,
                regions: Sequence[torch.Tensor]) -> Callable[[torch.Tensor, int], torch.Tensor] | None:
    """`RenderSettings.ref_dc` for one window: a sampler's `denoised_fn` that moves the clean estimate
    of each generated frame inside the region where its lighting must be inferred (`regions[p]`, (h, w)
    weights, `inferred_region`) so that the region's RGB latent mean per channel goes `strength` of
    the way to the linear interpolation, by window position, of the two references' means over their
    own regions; None where `anchor_positions` finds nothing to anchor.

    ref: (n, 4, h, w) the window's reference RGB latents; offset: (n, 4, h, w) what
    `sample_to_latents` adds to a sample at each position (the shading prior's latent, or 0)."""
    where = anchor_positions(window, strength, regions)
    if where is None:
        return None
    p0, p1, gen = where
    w_gen = torch.stack([regions[p] for p in gen])  # (G, h, w)
    m0, m1 = region_mean(ref[p0], regions[p0]), region_mean(ref[p1], regions[p1])  # (4,)
    lam = torch.tensor([(p - p0) / (p1 - p0) for p in gen], device=ref.device)[:, None]  # (G, 1)
    target = (1 - lam) * m0 + lam * m1  # (G, 4)

    def anchor(x0: torch.Tensor, i: int) -> torch.Tensor:
        x0 = x0.clone()
        now = region_mean(x0[gen] + offset[gen], w_gen)  # (G, 4)
        shift = strength * (target - now)[..., None, None] * w_gen.to(x0.device)[:, None]  # (G, 4, h, w)
        x0[gen] += shift.to(x0.dtype)
        return x0

    return anchor


_NO_TIMES = NoTimes()


def _check_pixel_bounds(settings: RenderSettings) -> None:
    for name in ("working_pixels", "residual_pixels"):
        if getattr(settings, name) < 0:
            raise ValueError(f"{name} must be 0 (full resolution) or more, got {getattr(settings, name)}")


class Renderer:
    """Drives a `RenderModel` over a shot; see the module docstring."""

    def __init__(self, model: RenderModel, *, cache: ConditioningCache | None = None, retain: bool = True) -> None:
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
        self._preparing: CancelToken | None = None  # the token of a `prepare` in progress; a render cancels it
        ours, theirs = alphas_cumprod(), model.alphas_cumprod().to(torch.float64).cpu()
        if ours.shape != theirs.shape or not torch.allclose(ours, theirs, atol=1e-6):
            raise ValueError(
                "the model's noise schedule is not the SD 2.1 zero-terminal-SNR schedule the samplers use "
                f"({theirs.shape[0]} steps, alpha_cumprod[0]={float(theirs[0]):.6f})"
            )

    @property
    def _clock(self) -> StageTimes | NoTimes:
        return self.timing if self.timing is not None else _NO_TIMES

    def _use_engine(self, settings: RenderSettings) -> None:
        """Point the model at `settings.engine` (models without engines, e.g. test fakes, run as they are)."""
        set_engine = getattr(self.model, "set_engine", None)
        self.engine = set_engine(settings.engine) if set_engine is not None else "torch"

    # -- for the editor and tests --------------------------------------------------
    def prepare(self, shot: Shot, settings: RenderSettings, edits: Any = None, cancel: CancelToken | None = None, *,
                base_dir: str | Path | None = None) -> int:
        """Encode ahead what a diffusion render of `shot` would encode first, into this Renderer's cache, and
        build the engine's graphs (`x2video.sampling.prepare`); returns the frames encoded. For a worker
        thread: a `render` started meanwhile cancels it and reuses what it finished."""
        from x2video.sampling.prepare import prepare

        token = cancel if cancel is not None else CancelToken()
        self._preparing = token
        try:
            return prepare(self, shot, settings, edits, token, base_dir=base_dir)
        finally:
            if self._preparing is token:
                self._preparing = None

    def cache_stats(self) -> CacheStats:
        return self.cache.stats()

    def plan(self, shot: Shot, settings: RenderSettings, ref_frame: int | None = None) -> list[Window]:
        """The windows a render of `shot` with `settings` runs (shot frame indices)."""
        start, stop = self._range(shot, settings)
        if ref_frame is not None:
            ref_frame = min(max(ref_frame, start), stop - 1) - start
        return shift(plan(settings.scheme, stop - start, settings.window, ref_frame, settings.seams, settings.max_levels), start)

    def choose_tier(self, shot: Shot, edits: Any, settings: RenderSettings) -> tiers.TierChoice:
        """The tier a render of `shot` with `edits` (or None) and `settings` runs with this model, and why
        (`x2video.sampling.tiers.choose_tier`); read from the edits' structure, so it costs nothing. A farm asks
        it before splitting a shot: tiers 0 and 1 ('formula', 'residual') are per frame."""
        return tiers.decide(settings.quality, shot, edits, self.model)

    # -- the render ------------------------------------------------------------------
    def render(
        self,
        shot: Shot,
        edits: Any,
        settings: RenderSettings,
        on_event: EventCallback | None = None,
        cancel: CancelToken | None = None,
        *,
        base_dir: str | Path | None = None,
    ) -> None:
        """Render `shot` with `edits` (an `x2video.edits.Edits`, or None for none).

        Emits RenderStarted, then per window WindowStarted, StepDone per step, FramesReady;
        then RenderFinished. Cancelling (between steps) emits RenderCancelled with the finished
        frames and returns. Any error emits RenderFailed and is re-raised. `base_dir` resolves
        relative paths of a reference image in the edits (the project file's folder).
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
        try:
            if settings.quality == "formula":  # tier 0: no network, albedo x irradiance frame by frame
                from x2video.sampling.formula import formula_frames

                return formula_frames(shot, edits, settings, emit, cancel, base_dir=base_dir)
            done: set[int] = set()  # frames delivered so far
            self.encode_seconds = 0.0
            try:
                self._render(shot, edits, settings, emit, cancel, base_dir, done)
            except Cancelled:
                log.info("render cancelled after %d frames", len(done))
                emit(RenderCancelled(frames_done=sorted(done)))
            except Exception as exc:
                emit(RenderFailed(error=f"{type(exc).__name__}: {exc}"))
                raise
        finally:
            if self.timing is not None:
                self.timing.total = time.perf_counter() - t0

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

    def _range(self, shot: Shot, settings: RenderSettings) -> tuple[int, int]:
        start, stop = settings.frames if settings.frames is not None else (0, shot.num_frames)
        if not 0 <= start < stop <= shot.num_frames:
            raise ValueError(f"frame range [{start}, {stop}) outside the shot's {shot.num_frames} frames")
        return start, stop

    def _validate(self, shot: Shot, settings: RenderSettings) -> RenderSettings:
        settings = select_steps(settings, self.model)
        if settings.sampler not in ("ddim", "lcm"):
            raise ValueError(f"unknown sampler {settings.sampler!r} (use 'ddim' or 'lcm')")
        if settings.sampler == "lcm" and not self.model.has_lcm:
            raise ValueError("sampler 'lcm' needs distilled LCM weights, and the loaded model has none")
        if settings.steps < 1:
            raise ValueError(f"steps must be at least 1, got {settings.steps}")
        if settings.noise not in ("window", "frame"):
            raise ValueError(f"unknown noise seeding {settings.noise!r} (use 'window' or 'frame')")
        if not 0.0 <= settings.noise_shared <= 1.0:
            raise ValueError(f"noise_shared must lie in [0, 1], got {settings.noise_shared}")
        if not 0.0 <= settings.ref_dc <= 1.0:
            raise ValueError(f"ref_dc must lie in [0, 1] (0 = off), got {settings.ref_dc}")
        if settings.resample < 1:
            raise ValueError(f"resample must be at least 1 (1 = off), got {settings.resample}")
        _check_pixel_bounds(settings)
        return settings

    def _setup(self, shot: Shot, edits: Any, settings: RenderSettings, base_dir: str | Path | None
               ) -> tuple[tiers.TierChoice, Callable[[int], FrameConditioning], Prompts, tuple[int, np.ndarray] | None]:
        """(tier, frame -> edited conditioning, prompts, the user's reference (frame, image) or None) of a render."""
        choice = self.choose_tier(shot, edits, settings)
        if edits is None:
            prompts, reference = Prompts(), None
            conditioning: Callable[[int], FrameConditioning] = functools.partial(plain_conditioning, shot)
        else:
            from x2video.edits import apply_edits, resolve_reference

            prompts = edits.prompts()
            reference = resolve_reference(shot, edits, base_dir) if choice.tier == "diffusion" else None
            conditioning = functools.partial(apply_edits, shot, edits)
        return choice, self._clock.wrap("read", conditioning), prompts, reference

    def _render(
        self,
        shot: Shot,
        edits: Any,
        settings: RenderSettings,
        emit: Callable[[RenderEvent], None],
        cancel: CancelToken | None,
        base_dir: str | Path | None,
        done: set[int],
    ) -> None:
        t0 = time.perf_counter()
        _check_pixel_bounds(settings)  # tier 1 reads residual_pixels before `_validate` runs
        choice, conditioning, prompts, reference = self._setup(shot, edits, settings, base_dir)
        self.last_tier = choice
        log.info("quality %s: tier %s (%s)", settings.quality, choice.tier, choice.reason)
        if choice.tier == "formula":  # auto chose tier 0
            from x2video.sampling.formula import formula_frames

            formula_frames(shot, edits, settings, emit, cancel, reason=choice.reason)
            return
        if choice.tier == "residual":
            self._render_direct(shot, settings, choice, conditioning, emit, cancel, done, t0)
            return
        run = self._diffusion(shot, settings, choice, conditioning, prompts, reference, emit)
        windows, emit = run.windows, run.emit
        keep_until = last_use(windows)
        with torch.inference_mode():
            levels = sorted({w.level for w in windows}, reverse=True)
            emit(RenderStarted(num_frames=len({f for w in windows for f in w.generate}), num_windows=len(windows), levels=levels,
                               tier=choice.tier, reason=choice.reason))
            latents: dict[int, torch.Tensor] = {}  # frame -> (4, h, w), only while a later window reads it
            self.peak_latents = 0
            cond_until = {f: i for i, w in enumerate(windows) for f in w.frames}  # frame -> last window encoding it
            for index, window in enumerate(windows):
                x0 = self._window(run, index, latents, cancel, done)
                for pos, f in zip(window.generate_positions, window.generate):
                    if keep_until.get(f, -1) > index:
                        latents[f] = x0[pos].clone()
                self.peak_latents = max(self.peak_latents, len(latents))
                for f in window.refs:
                    if keep_until.get(f) == index:
                        latents.pop(f, None)
                run.decode(index, x0, done)
                if not self.retain:
                    self._release(run, cond_until, index)
        emit(RenderFinished(num_frames=len(done), seconds=time.perf_counter() - t0))

    def _diffusion(self, shot: Shot, settings: RenderSettings, choice: tiers.TierChoice, conditioning: Callable[[int], FrameConditioning],
                   prompts: Prompts, reference: tuple[int, np.ndarray] | None, emit: Callable[[RenderEvent], None]) -> "_DiffusionRun":
        """What every window of a diffusion render shares: its plan, the network's conditioning (any frame size:
        large frames run at a working resolution, the network's residual over the formula brought back on the
        full-resolution formula (x2video.sampling.working); others reflect-pad to the model's factor, decoded frames
        cropped back), the validated settings, the text encodings and the reference latent."""
        model = self.model
        net = getattr(model, "residual_net", None)
        height, width = shot.size
        full_conditioning = conditioning
        work = working.working_size((height, width), model.downsample, settings.working_pixels)
        ph, pw = (0, 0) if work is not None else pad_amounts((height, width), model.downsample)
        if work is not None:
            log.info("shot size %dx%d: the diffusion network runs at %dx%d (working_pixels %d), its residual over the formula"
                     " brought back on the full-resolution formula", width, height, work[1], work[0], settings.working_pixels)
            conditioning = lambda t: working.downsample_conditioning(full_conditioning(t), work)  # noqa: E731
            if reference is not None:
                reference = (reference[0], working.resize_area(reference[1], work))
        elif ph or pw:
            log.info("shot size %dx%d: reflect-padded to %dx%d (the model's factor %d), frames cropped back",
                     width, height, width + pw, height + ph, model.downsample)
            conditioning = lambda t: pad_conditioning(full_conditioning(t), ph, pw)  # noqa: E731
            if reference is not None:
                reference = (reference[0], pad_image(reference[1], ph, pw))
        settings = self._validate(shot, settings)
        self._use_engine(settings)
        if choice.regions:
            emit = self._composite(emit, full_conditioning, net if choice.base == "residual" else None, settings.guess_unseen,
                                   settings.residual_pixels)
        windows = self.plan(shot, settings, None if reference is None else reference[0])
        with torch.inference_mode():
            text_global = model.encode_prompts([prompts.global_prompt])  # (1, L, D)
            text_local = model.encode_prompts(list(prompts.local))  # (P, L, D)
            ref_latent = None if reference is None else model.encode_image(reference[1])  # (4, h, w)
        return _DiffusionRun(self, settings, windows, conditioning, full_conditioning, work, (height, width), emit, text_global, text_local,
                             ref_latent)

    def _window(self, run: "_DiffusionRun", index: int, latents: dict[int, torch.Tensor], cancel: CancelToken | None,
                done: set[int]) -> torch.Tensor:
        """Denoise window `index` of `run` with the reference latents `latents` (frame -> (4, h, w)); returns its (n, 4, h, w)
        RGB latents (what later windows read) and keeps what `_DiffusionRun.decode` needs to deliver its frames."""
        if cancel is not None and cancel.cancelled:
            raise Cancelled(f"cancelled before window {index}")
        window = run.windows[index]
        run.emit(WindowStarted(index=index, frames=list(window.frames), mode=window.mode, level=window.level))
        run.started = time.perf_counter()
        x0, run.conds, run.keys, run.cond = self._run_window(index, window, run.settings, run.conditioning, latents, run.ref_latent,
                                                             run.text_global, run.text_local, run.emit, cancel)
        return self.model.sample_to_latents(x0, run.cond)  # RGB latents: later windows read them as references

    def render_plan(self, shot: Shot, edits: Any, settings: RenderSettings, *, base_dir: str | Path | None = None) -> list[Window]:
        """The windows a diffusion-tier render of `shot` with `edits` and `settings` runs (anchored at the user's
        reference frame where the edits have one); `render_windows` takes their indices. ValueError when the render's
        tier is not 'diffusion' (tiers 0 and 1 have no windows: every frame is its own)."""
        choice, _, _, reference = self._setup(shot, edits, settings, base_dir)
        if choice.tier != "diffusion":
            raise ValueError(f"this render runs tier {choice.tier!r} ({choice.reason}), which has no windows")
        return self.plan(shot, self._validate(shot, settings), None if reference is None else reference[0])

    def render_windows(self, shot: Shot, edits: Any, settings: RenderSettings, indices: Sequence[int], refs: dict[int, torch.Tensor],
                       on_event: EventCallback | None = None, cancel: CancelToken | None = None, *,
                       base_dir: str | Path | None = None) -> dict[int, dict[int, torch.Tensor]]:
        """Render only the windows `indices` (of `render_plan`, in plan order) of a diffusion render, given `refs`: frame ->
        (4, h, w) RGB latent of every reference frame they read and do not make themselves (the latents an earlier
        call returned). Returns, per window, its generated frames' RGB latents; emits WindowStarted, StepDone and
        FramesReady for its frames (not RenderStarted/RenderFinished: this is part of a render).

        The windows of one recursive level read only frames of the levels above, so a farm runs them in parallel
        (`x2video.farm`). `render` runs each window through the same steps (the noise is seeded per frame or per
        window, the conditioning per frame), so the frames equal a single `render`'s."""
        if list(indices) != sorted(set(indices)):
            raise ValueError(f"window indices must ascend without repeats (plan order), got {list(indices)}")
        emit: Callable[[RenderEvent], None] = on_event if on_event is not None else (lambda e: None)
        choice, conditioning, prompts, reference = self._setup(shot, edits, settings, base_dir)
        if choice.tier != "diffusion":
            raise ValueError(f"this render runs tier {choice.tier!r} ({choice.reason}), which has no windows")
        windows = self.plan(shot, self._validate(shot, settings), None if reference is None else reference[0])
        made_here: set[int] = set()
        for i in indices:  # checked before the engine is built
            if not 0 <= i < len(windows):
                raise ValueError(f"window {i} is not in the plan ({len(windows)} windows)")
            missing = [f for f in windows[i].refs if f not in made_here and f not in refs]
            if missing:
                raise ValueError(f"window {i} reads frames {missing} as references: pass their latents in refs")
            made_here.update(windows[i].generate)
        run = self._diffusion(shot, settings, choice, conditioning, prompts, reference, emit)
        latents = {f: v.to(self.model.device, self.model.dtype) for f, v in refs.items()}
        out: dict[int, dict[int, torch.Tensor]] = {}
        done: set[int] = set()
        cond_until = {f: i for i in indices for f in run.windows[i].frames}
        with torch.inference_mode():
            for i in indices:
                window = run.windows[i]
                x0 = self._window(run, i, latents, cancel, done)
                made = {f: x0[p].clone() for p, f in zip(window.generate_positions, window.generate)}
                latents.update(made)
                out[i] = made
                run.decode(i, x0, done)
                if not self.retain:
                    self._release(run, cond_until, i)
        return out

    def _release(self, run: "_DiffusionRun", cond_until: dict[int, int], index: int) -> None:
        """`retain=False`: drop from the cache what window `index` of `run` (just decoded) was the last to read: every
        detail (read once, at decoding) and the conditioning latents of frames no later window holds
        (`cond_until`: frame -> its last window)."""
        window = run.windows[index]
        self.cache.discard([k + "#detail" for k in run.keys] + [k for f, k in zip(window.frames, run.keys) if cond_until[f] == index])

    def _render_direct(self, shot: Shot, settings: RenderSettings, choice: tiers.TierChoice, conditioning: Callable[[int], FrameConditioning],
                       emit: Callable[[RenderEvent], None], cancel: CancelToken | None, done: set[int], t0: float) -> None:
        """Tiers 0 and 1: every frame on its own, coarse to fine (the timeline fills evenly), a few per event;
        the first frame alone, so it shows as soon as one pass allows (an editor waits for it)."""
        start, stop = self._range(shot, settings)
        order = tiers.coarse_to_fine(start, stop)
        emit(RenderStarted(num_frames=len(order), num_windows=0, levels=[0], tier=choice.tier, reason=choice.reason))
        net = getattr(self.model, "residual_net", None)
        batch = 4
        work = working.working_size(shot.size, net.cfg.factor, settings.residual_pixels) if choice.tier == "residual" else None
        if work is not None:
            log.info("shot size %dx%d: the tier-1 net runs at %dx%d (residual_pixels %d), its correction of the formula brought"
                     " back on the full-resolution formula", shot.size[1], shot.size[0], work[1], work[0], settings.residual_pixels)
        for index, i in enumerate([0, *range(1, len(order), batch)]):
            if cancel is not None and cancel.cancelled:
                raise Cancelled(f"cancelled after {len(done)} frames")
            tw = time.perf_counter()
            fs = order[i:i + batch] if i else order[:1]
            conds = [conditioning(f) for f in fs]
            if choice.tier == "residual":
                with self._clock.stage("residual"):
                    images = tiers.residual_frames(net, conds, self.model.device, batch, settings.guess_unseen, settings.residual_pixels)
            else:
                images = [tiers.formula_frame(c) for c in conds]
            done.update(fs)
            emit(FramesReady(window=index, frames=dict(zip(fs, images)), level=0, mode=choice.tier, seconds=time.perf_counter() - tw))
        emit(RenderFinished(num_frames=len(done), seconds=time.perf_counter() - t0))

    def _composite(self, emit: Callable[[RenderEvent], None], conditioning: Callable[[int], FrameConditioning], net,
                   guess_unseen: bool = False, max_pixels: int = 0) -> Callable[[RenderEvent], None]:
        """Wrap `emit` so each generated frame keeps tier 2 only inside its A|M|R regions and local prompts' masks
        (`tiers.generated_region`, feathered), tier 1 elsewhere
        (the formula where `net` is None: auto's choice when the tier-1 net is not trusted)."""

        def wrapped(event: RenderEvent) -> None:
            if isinstance(event, FramesReady):
                fs = list(event.frames)
                conds = [conditioning(f) for f in fs]
                with self._clock.stage("residual"):
                    base = (tiers.residual_frames(net, conds, self.model.device, guess_unseen=guess_unseen, max_pixels=max_pixels) if net is not None
                            else [formula(c.channels, np.shape(c.amr_mask)[:2] if np.size(c.amr_mask) else None) for c in conds])
                frames = {}
                for f, c, b in zip(fs, conds, base):
                    w = tiers.feathered(tiers.generated_region(c))[..., None]  # (H, W, 1)
                    frames[f] = (w * event.frames[f] + (1 - w) * b).astype(np.float32)
                event = dataclasses.replace(event, frames=frames)
            emit(event)

        return wrapped

    def _cached(self, keys: list[str], compute: Callable[[list[int]], torch.Tensor]) -> torch.Tensor:
        """Stack of the cache's tensors for `keys`; `compute(positions)` makes the missing ones (each
        distinct key once, at its first position) and its wall time counts as encoding time."""
        found = [self.cache.get(k) for k in keys]
        missing: dict[str, int] = {}  # key -> first position with that content
        for i, v in enumerate(found):
            if v is None:
                missing.setdefault(keys[i], i)
        if missing:
            t0 = time.perf_counter()
            fresh = compute(list(missing.values()))
            self.encode_seconds += time.perf_counter() - t0
            made = {k: fresh[j].clone() for j, k in enumerate(missing)}
            for k, v in made.items():
                self.cache.put(k, v)
            found = [made[keys[i]] if v is None else v for i, v in enumerate(found)]
        return torch.stack(found)

    def _encode(self, conds: list[FrameConditioning], keys: list[str]) -> torch.Tensor:
        """(n, C_cond, h, w) conditioning latents, encoding only frames the cache lacks (one batch)."""
        with self._clock.stage("encode"):
            return self._cached(keys, lambda idx: self.model.encode_frames([conds[i] for i in idx]))

    def _detail(self, conds: list[FrameConditioning], keys: list[str], cond: torch.Tensor) -> np.ndarray | None:
        """(G, H, W, 3) `model.detail` of the generated frames, cached beside their conditioning latents in half
        precision (a full-resolution image per frame, twice its latents in float32: 1,000 frames at 320x224 hold
        0.4 GB instead of 0.8; EXR output is half float anyway), used in that precision on every render alike."""
        if not self.model.residual_prior:
            return None

        def compute(idx: list[int]) -> torch.Tensor:
            d = self.model.detail([conds[i] for i in idx], cond[idx])
            assert d is not None  # residual models always have a detail
            return torch.from_numpy(d).half()

        return self._cached([k + "#detail" for k in keys], compute).float().numpy()

    def _run_window(
        self,
        index: int,
        window: Window,
        settings: RenderSettings,
        conditioning: Callable[[int], FrameConditioning],
        latents: dict[int, torch.Tensor],
        ref_latent: torch.Tensor | None,
        text_global: torch.Tensor,
        text_local: torch.Tensor,
        emit: Callable[[RenderEvent], None],
        cancel: CancelToken | None,
    ) -> tuple[torch.Tensor, list[FrameConditioning], list[str], torch.Tensor]:
        """Denoise one window; returns the sampler's clean output (n, 4, h, w), the frames'
        conditioning, their cache keys and their (n, C_cond, h, w) conditioning latents."""
        model = self.model
        conds = [conditioning(f) for f in window.frames]
        model_key = model.content_key()
        keys = [conditioning_key(c, model_key) for c in conds]
        cond = self._encode(conds, keys)  # (n, C_cond, h, w)
        n, _, h, w = cond.shape
        ref = torch.zeros(n, model.latent_channels, h, w, device=model.device, dtype=model.dtype)  # (n, 4, h, w)
        if window.user_ref:
            ref[0] = ref_latent
        for f in window.refs:
            ref[window.frames.index(f)] = latents[f]
        for c in conds:
            if c.local_masks.shape[0] != text_local.shape[0]:
                raise ValueError(
                    f"frame {c.frame_index}: {c.local_masks.shape[0]} local prompt masks for {text_local.shape[0]} local prompts"
                )
        masks = np.stack([c.local_masks for c in conds]).astype(np.float32)  # (n, P, H, W)
        inputs = WindowInputs(
            cond=cond,
            ref=ref,
            ref_positions=window.ref_positions,
            mode=window.mode,
            level=window.level,
            text_global=text_global,
            text_local=text_local,
            local_masks=torch.from_numpy(masks).to(model.device, model.dtype),
        )
        gen = torch.Generator(device="cpu").manual_seed(window_seed(settings.seed, window))
        if settings.noise == "frame":
            noise = frame_noise(settings.seed, window.frames, (model.latent_channels, h, w), settings.noise_shared)
        else:
            noise = torch.randn(n, model.latent_channels, h, w, generator=gen)  # (n, 4, h, w), CPU so devices agree
        x_T = noise.to(model.device, model.dtype)
        lcm = settings.sampler == "lcm"
        known = None
        if settings.replace_refs and window.refs:
            pos = tuple(window.frames.index(f) for f in window.refs)
            rgb = ref[list(pos)]  # (r, 4, h, w) the references' RGB latents
            # in sample space: sample_to_latents adds a fixed offset (the shading prior's latent
            # for residual models, else 0), which a zero sample reveals
            offset = model.sample_to_latents(torch.zeros_like(rgb), cond[list(pos)])
            known = Known(pos, rgb - offset, x_T[list(pos)])

        def model_fn(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
            with clock.stage("unet"):
                return model.predict_v(x, t, inputs, lcm=lcm)

        clock = self._clock

        denoised_fn = mean_anchor(window, settings.ref_dc, ref, model.sample_to_latents(torch.zeros_like(x_T), cond),
                                  [inferred_region(c, (h, w)) for c in conds])

        def callback(info: dict[str, Any]) -> None:
            emit(StepDone(window=index, step=info["i"] + 1, steps=info["steps"]))

        if lcm:
            renoise = None
            if settings.noise == "frame":
                def renoise(i: int) -> torch.Tensor:
                    return frame_noise(settings.seed, window.frames, (model.latent_channels, h, w), settings.noise_shared, i + 1)
            x0 = sample_lcm(model_fn, x_T, settings.steps, callback=callback, cancel=cancel, generator=gen, known=known, renoise=renoise,
                            denoised_fn=denoised_fn)
        else:
            def jump_noise(i: int, j: int) -> torch.Tensor:
                if settings.noise == "frame":  # per frame, so a frame's noise does not depend on its window
                    return frame_noise(settings.seed, window.frames, (model.latent_channels, h, w), settings.noise_shared, 1000 + 64 * i + j)
                return torch.randn(n, model.latent_channels, h, w, generator=gen)

            x0 = sample_ddim(model_fn, x_T, settings.steps, callback=callback, cancel=cancel, known=known,
                             resample=settings.resample, jump_noise=jump_noise, denoised_fn=denoised_fn)
        return x0, conds, keys, cond


class _DiffusionRun:
    """One diffusion render's shared state (`Renderer._diffusion`), and the decoding of a window's frames into
    `FramesReady` events (the detail pass, working-size or padded frames back to the shot's size)."""

    def __init__(self, renderer: Renderer, settings: RenderSettings, windows: list[Window], conditioning: Callable[[int], FrameConditioning],
                 full_conditioning: Callable[[int], FrameConditioning], work: tuple[int, int] | None, size: tuple[int, int],
                 emit: Callable[[RenderEvent], None], text_global: torch.Tensor, text_local: torch.Tensor, ref_latent: torch.Tensor | None) -> None:
        self.renderer, self.settings, self.windows = renderer, settings, windows
        self.conditioning, self.full_conditioning, self.work, self.size, self.emit = conditioning, full_conditioning, work, size, emit
        self.text_global, self.text_local, self.ref_latent = text_global, text_local, ref_latent
        # the window in progress (`Renderer._window`): its frames' conditioning, cache keys and latents, its start
        self.conds: list[FrameConditioning] = []
        self.keys: list[str] = []
        self.cond: torch.Tensor | None = None
        self.started = 0.0

    def decode(self, index: int, x0: torch.Tensor, done: set[int]) -> None:
        """Decode the window just run (RGB latents `x0`) and emit its frames; `done`: frames delivered before (the seam
        pass makes frames a second time: `FramesReady.replaces`)."""
        r, model, window = self.renderer, self.renderer.model, self.windows[index]
        height, width = self.size
        gen_pos = list(window.generate_positions)
        # the first window's first frame is decoded and delivered on its own: an editor shows it while the
        # rest of the window decodes (the decoder's batch is free; the frames are the same either way)
        chunks = [gen_pos[:1], gen_pos[1:]] if index == 0 and len(gen_pos) > 1 else [gen_pos]
        for part, chunk in enumerate(chunks):
            with r._clock.stage("decode"):
                images = model.decode(x0[chunk])  # (G, H, W, 3)
            if self.settings.detail:
                with r._clock.stage("detail"):
                    assert self.cond is not None
                    detail = r._detail([self.conds[p] for p in chunk], [self.keys[p] for p in chunk], self.cond[chunk])
                if detail is not None:
                    images = np.maximum(images + detail, 0)
            made = [window.frames[p] for p in chunk]
            if self.work is not None:
                frames = {f: working.to_full(images[i], self.full_conditioning(f)) for i, f in enumerate(made)}
            else:
                frames = {f: np.ascontiguousarray(images[i][:height, :width], dtype=np.float32) for i, f in enumerate(made)}
            again = tuple(f for f in made if f in done)  # the seam pass makes frames a second time
            done.update(made)
            self.emit(FramesReady(window=index, frames=frames, level=window.level, mode=window.mode, seconds=time.perf_counter() - self.started,
                                  replaces=again, window_done=part == len(chunks) - 1))
