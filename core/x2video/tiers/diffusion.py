"""Tier 2, the diffusion sampler: Recursive Sampling window by window (paper Sec. Recursive Sampling, Sec. Acceleration).

For what must be generated: a dropped channel, a region whose albedo/material is masked out (A|M|R), a local
prompt, a reference. Per render: prompts encoded once, each frame's conditioning encoded once through the
content-keyed cache (`x2video.tiers.encoder.Encoder`), initial noise seeded per window or frame
(`x2video.sampling.samplers`), and only the latents later windows read as references kept; decoded frames leave
through `FramesReady` events. A regional render keeps the sampler's pixels inside the generated regions only,
over the base tier's frame (`TierChoice.base`), the seam feathered just inside the region.
"""
from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np
import torch

from x2video.conditioning.cache import conditioning_key
from x2video.conditioning.frame import FrameConditioning
from x2video.conditioning.network import NetworkConditioning, working_size
from x2video.edits.model import Prompts
from x2video.model.api import RenderModel, WindowInputs
from x2video.render.events import Cancelled, CancelToken, FramesReady, RenderEvent, RenderStarted, StepDone, WindowStarted
from x2video.render.settings import RenderSettings, resolve, select_steps
from x2video.sampling.planner import Window, last_use, plan, plan_keyframed, shift
from x2video.sampling.samplers import Known, frame_noise, inferred_region, mean_anchor, sample_ddim, sample_lcm, window_seed
from x2video.tiers.base import TIERS, Emit, PerFrameTier, RenderJob, RenderPlan, Tier
from x2video.tiers.encoder import Encoder
from x2video.tiers.regions import composite_weight, generated_region

if TYPE_CHECKING:
    from x2video.edits.model import Edits
    from x2video.shot import Shot


def reference_frame(edits: Edits | None) -> int | None:
    """The shot frame the edits' reference sits at (a shot frame, or where an image is placed), or None; read from the
    edits' structure (no image is read), so planning stays pure."""
    ref = None if edits is None else edits.reference
    if ref is None:
        return None
    return ref.frame if ref.frame is not None else ref.position


def diffusion_windows(frames: tuple[int, int], settings: RenderSettings, ref_frame: int | None = None,
                      keyframes: Sequence[int] = ()) -> list[Window]:
    """The windows a diffusion render of shot frames [start, stop) runs (shot frame indices), anchored at `ref_frame`; or,
    given path-traced `keyframes` (`given_keyframes`), around those of them inside the range (`plan_keyframed`)."""
    start, stop = frames
    keys = [k - start for k in keyframes if start <= k < stop]
    if keys:
        if ref_frame is not None:
            raise ValueError("a reference frame and keyframes as references exclude each other (fill 'diffusion' renders no edits)")
        return shift(plan_keyframed(stop - start, settings.window, keys, settings.scheme, settings.max_levels), start)
    if ref_frame is not None:
        ref_frame = min(max(ref_frame, start), stop - 1) - start
    return shift(plan(settings.scheme, stop - start, settings.window, ref_frame, settings.seams, settings.max_levels), start)


def given_keyframes(shot: Shot, settings: RenderSettings, frames: tuple[int, int]) -> tuple[int, ...]:
    """The shot's path-traced keyframes inside `frames` that a render with `settings` reads as references instead of
    making them (`RenderSettings.fill` 'diffusion': `x2video.base.keyframes.reference_keyframes`)."""
    from x2video.base.keyframes import reference_keyframes

    start, stop = frames
    return tuple(k for k in reference_keyframes(shot, settings) if start <= k < stop)


class DiffusionTier(Tier):
    """Tier 2: the video diffusion sampler over windows of frames."""

    name = "diffusion"
    reads_reference = True
    generative = True

    def with_preset(self, settings: RenderSettings, model: RenderModel | None) -> RenderSettings:
        """The preset resolved into a sampler and steps for `model` (`select_steps`)."""
        return select_steps(settings, model)

    def working_size(self, size: tuple[int, int], settings: RenderSettings, model: RenderModel | None) -> tuple[int, int] | None:
        """The working resolution of large frames (`NetworkConditioning`: `RenderSettings.working_pixels`)."""
        assert model is not None
        return working_size(size, model.downsample, settings.working_pixels)

    def plan(self, shot, edits, settings, model, choice, frames) -> RenderPlan:
        resolved = resolve(settings, model)
        windows = diffusion_windows(frames, resolved, reference_frame(edits), given_keyframes(shot, settings, frames))
        return RenderPlan(choice.tier, choice.reason, frames, per_frame=False, windows=tuple(windows), sampler=resolved.sampler,
                          steps=resolved.steps)

    def render(self, job: RenderJob, emit: Emit, cancel: CancelToken | None, done: set[int]) -> None:
        run = DiffusionRun(job, emit)
        windows, emit = run.windows, run.emit
        keep_until = last_use(windows)
        with torch.inference_mode():
            levels = sorted({w.level for w in windows}, reverse=True)
            emit(RenderStarted(num_frames=len({f for w in windows for f in w.generate} | set(run.given)), num_windows=len(windows),
                               levels=levels, tier=job.choice.tier, reason=job.choice.reason))
            run.deliver_given(done)
            latents = run.given_latents(keep_until)  # frame -> (4, h, w), only while a later window reads it
            job.stats["peak_latents"] = 0
            cond_until = {f: i for i, w in enumerate(windows) for f in w.frames}  # frame -> last window encoding it
            for index, window in enumerate(windows):
                x0 = run.window(index, latents, cancel, done)
                for pos, f in zip(window.generate_positions, window.generate):
                    if keep_until.get(f, -1) > index:
                        latents[f] = x0[pos].clone()
                job.stats["peak_latents"] = max(job.stats["peak_latents"], len(latents))
                for f in window.refs:
                    if keep_until.get(f) == index:
                        latents.pop(f, None)
                run.decode(index, x0, done)
                if not job.retain:
                    run.release(cond_until, index)

    def render_windows(self, job: RenderJob, indices: Sequence[int], refs: dict[int, torch.Tensor], emit: Emit,
                       cancel: CancelToken | None) -> dict[int, dict[int, torch.Tensor]]:
        """`Renderer.render_windows`: only the windows `indices` of the plan, given the reference latents `refs`."""
        if list(indices) != sorted(set(indices)):
            raise ValueError(f"window indices must ascend without repeats (plan order), got {list(indices)}")
        ref_frame = None if job.reference is None else job.reference[0]
        given = given_keyframes(job.shot, job.settings, job.frames)
        windows = diffusion_windows(job.frames, resolve(job.settings, job.model), ref_frame, given)
        made_here: set[int] = set(given)  # path-traced keyframes: encoded here, never passed in
        for i in indices:  # checked before the engine is built
            if not 0 <= i < len(windows):
                raise ValueError(f"window {i} is not in the plan ({len(windows)} windows)")
            missing = [f for f in windows[i].refs if f not in made_here and f not in refs]
            if missing:
                raise ValueError(f"window {i} reads frames {missing} as references: pass their latents in refs")
            made_here.update(windows[i].generate)
        run = DiffusionRun(job, emit)
        model = run.model
        with torch.inference_mode():
            latents = run.given_latents({f: 0 for i in indices for f in run.windows[i].refs})
        latents.update({f: v.to(model.device, model.dtype) for f, v in refs.items()})
        out: dict[int, dict[int, torch.Tensor]] = {}
        done: set[int] = set()
        cond_until = {f: i for i in indices for f in run.windows[i].frames}
        with torch.inference_mode():
            for i in indices:
                window = run.windows[i]
                x0 = run.window(i, latents, cancel, done)
                made = {f: x0[p].clone() for p, f in zip(window.generate_positions, window.generate)}
                latents.update(made)
                out[i] = made
                run.decode(i, x0, done)
                if not job.retain:
                    run.release(cond_until, i)
        return out


def composite(job: RenderJob, emit: Emit, base: PerFrameTier) -> Emit:
    """Wrap `emit` so each generated frame keeps tier 2 only inside its A|M|R regions and local prompts' masks
    (`generated_region`, with the seam just inside it: `composite_weight`), `base`'s frame elsewhere (`PerFrameTier.base_frames`)."""

    def wrapped(event: RenderEvent) -> None:
        if isinstance(event, FramesReady):
            fs = list(event.frames)
            conds = [job.conditioning(f) for f in fs]
            under = base.base_frames(job, conds)
            frames = {}
            for f, c, b in zip(fs, conds, under):
                w = composite_weight(generated_region(c))[..., None]  # (H, W, 1), the seam inside the region
                frames[f] = (w * event.frames[f] + (1 - w) * b).astype(np.float32)
            event = dataclasses.replace(event, frames=frames)
        emit(event)

    return wrapped


class DiffusionRun:
    """One diffusion render's shared state: its plan, the network's conditioning (any frame size: large frames run at a
    working resolution, the network's residual over the formula brought back on the full-resolution formula; others
    reflect-pad to the model's factor, decoded frames cropped back), the resolved settings, the text encodings and
    the reference latent; and the denoising (`window`) and decoding (`decode`) of one window."""

    def __init__(self, job: RenderJob, emit: Emit) -> None:
        assert job.model is not None
        self.job = job
        model: RenderModel = job.model
        self.model = model
        #: the network's view of the frames, settled once: its size, and the way back to the shot's
        self.net = NetworkConditioning.for_model(job.shot.size, job.conditioning, model.downsample, job.settings.working_pixels, job.reference)
        self.settings = resolve(job.settings, model)
        job.stats["engine"] = model.set_engine(self.settings.engine)
        if job.choice.regions:
            base = TIERS[job.choice.base]()
            assert isinstance(base, PerFrameTier)
            emit = composite(job, emit, base)
        self.emit = emit
        self.encoder = Encoder(model, job.cache, job.clock)
        reference = self.net.reference
        #: path-traced keyframes read as references and delivered as they are (`RenderSettings.fill` 'diffusion')
        self.given = given_keyframes(job.shot, job.settings, job.frames)
        self.windows = diffusion_windows(job.frames, self.settings, None if reference is None else reference[0], self.given)
        prompts = Prompts() if job.edits is None else job.edits.prompts()
        with torch.inference_mode():
            self.text_global = model.encode_prompts([prompts.global_prompt])  # (1, L, D)
            self.text_local = model.encode_prompts(list(prompts.local))  # (P, L, D)
            self.ref_latent = None if reference is None else model.encode_image(reference[1])  # (4, h, w)
        # the window in progress (`window`): its frames' conditioning, cache keys and latents, its start
        self.conds: list[FrameConditioning] = []
        self.keys: list[str] = []
        self.cond: torch.Tensor | None = None
        self.started = 0.0

    def given_image(self, t: int) -> np.ndarray:
        """Keyframe t's path-traced frame in the model's exposure, float64 (`x2video.base.fill.BaseFrames`)."""
        from x2video.base.fill import BaseFrames

        return BaseFrames(self.job.shot)(t)

    def given_latents(self, read: dict[int, int]) -> dict[int, torch.Tensor]:
        """frame -> (4, h, w) RGB latent of each given keyframe some window reads (`read`: frame -> a window reading it)."""
        model = self.model
        out = {}
        for t in self.given:
            if t in read:
                with self.job.clock.stage("encode"):
                    out[t] = model.encode_image(self.net.image(self.given_image(t).astype(np.float32))).to(model.device, model.dtype)
        return out

    def deliver_given(self, done: set[int]) -> None:
        """Emit the given keyframes as they are (the base stage's exact frames, mode 'base'), a few per event, before any
        window runs."""
        from x2video.base.stage import BASE

        for i in range(0, len(self.given), 4):
            t0 = time.perf_counter()
            frames = {t: self.given_image(t) for t in self.given[i:i + 4]}
            done.update(frames)
            self.emit(FramesReady(window=-1, frames=frames, level=0, mode=BASE, seconds=time.perf_counter() - t0, window_done=False))

    def release(self, cond_until: dict[int, int], index: int) -> None:
        """`retain=False`: drop from the cache what window `index` (just decoded) was the last to read: every detail (read
        once, at decoding) and the conditioning latents of frames no later window holds (`cond_until`: frame -> its last window)."""
        window = self.windows[index]
        self.job.cache.discard([k + "#detail" for k in self.keys] + [k for f, k in zip(window.frames, self.keys) if cond_until[f] == index])

    def window(self, index: int, latents: dict[int, torch.Tensor], cancel: CancelToken | None, done: set[int]) -> torch.Tensor:
        """Denoise window `index` with the reference latents `latents` (frame -> (4, h, w)); returns its (n, 4, h, w)
        RGB latents (what later windows read) and keeps what `decode` needs to deliver its frames."""
        if cancel is not None and cancel.cancelled:
            raise Cancelled(f"cancelled before window {index}")
        window = self.windows[index]
        self.emit(WindowStarted(index=index, frames=list(window.frames), mode=window.mode, level=window.level))
        self.started = time.perf_counter()
        x0 = self._denoise(index, window, latents, cancel)
        self.job.stats["encode_seconds"] = self.encoder.seconds
        return self.model.sample_to_latents(x0, self.cond)  # RGB latents: later windows read them as references

    def _denoise(self, index: int, window: Window, latents: dict[int, torch.Tensor], cancel: CancelToken | None) -> torch.Tensor:
        """Run the sampler over one window; returns its clean output (n, 4, h, w) and keeps the frames' conditioning,
        their cache keys and their (n, C_cond, h, w) conditioning latents."""
        model, settings, clock = self.model, self.settings, self.job.clock
        conds = [self.net.frame(f) for f in window.frames]
        model_key = model.content_key()
        keys = [conditioning_key(c, model_key) for c in conds]
        cond = self.encoder.encode(conds, keys)  # (n, C_cond, h, w)
        self.conds, self.keys, self.cond = conds, keys, cond
        n, _, h, w = cond.shape
        ref = torch.zeros(n, model.latent_channels, h, w, device=model.device, dtype=model.dtype)  # (n, 4, h, w)
        if window.user_ref:
            ref[0] = self.ref_latent
        for f in window.refs:
            ref[window.frames.index(f)] = latents[f]
        text_local = self.text_local
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
            text_global=self.text_global,
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

        denoised_fn = mean_anchor(window, settings.ref_dc, ref, model.sample_to_latents(torch.zeros_like(x_T), cond),
                                  [inferred_region(c, (h, w)) for c in conds])

        def callback(info: dict[str, Any]) -> None:
            self.emit(StepDone(window=index, step=info["i"] + 1, steps=info["steps"]))

        if lcm:
            renoise: Callable[[int], torch.Tensor] | None = None
            if settings.noise == "frame":
                def renoise(i: int) -> torch.Tensor:
                    return frame_noise(settings.seed, window.frames, (model.latent_channels, h, w), settings.noise_shared, i + 1)
            return sample_lcm(model_fn, x_T, settings.steps, callback=callback, cancel=cancel, generator=gen, known=known, renoise=renoise,
                              denoised_fn=denoised_fn)

        def jump_noise(i: int, j: int) -> torch.Tensor:
            if settings.noise == "frame":  # per frame, so a frame's noise does not depend on its window
                return frame_noise(settings.seed, window.frames, (model.latent_channels, h, w), settings.noise_shared, 1000 + 64 * i + j)
            return torch.randn(n, model.latent_channels, h, w, generator=gen)

        return sample_ddim(model_fn, x_T, settings.steps, callback=callback, cancel=cancel, known=known,
                           resample=settings.resample, jump_noise=jump_noise, denoised_fn=denoised_fn)

    def decode(self, index: int, x0: torch.Tensor, done: set[int]) -> None:
        """Decode the window just run (RGB latents `x0`) and emit its frames; `done`: frames delivered before (the seam
        pass makes frames a second time: `FramesReady.replaces`)."""
        model, window, clock = self.model, self.windows[index], self.job.clock
        gen_pos = list(window.generate_positions)
        # the first window's first frame is decoded and delivered on its own: an editor shows it while the
        # rest of the window decodes (the decoder's batch is free; the frames are the same either way)
        chunks = [gen_pos[:1], gen_pos[1:]] if index == 0 and len(gen_pos) > 1 else [gen_pos]
        for part, chunk in enumerate(chunks):
            with clock.stage("decode"):
                images = model.decode(x0[chunk])  # (G, H, W, 3)
            if self.settings.detail:
                with clock.stage("detail"):
                    assert self.cond is not None
                    detail = self.encoder.detail([self.conds[p] for p in chunk], [self.keys[p] for p in chunk], self.cond[chunk])
                if detail is not None:
                    images = np.maximum(images + detail, 0)
            made = [window.frames[p] for p in chunk]
            frames = {f: self.net.output(images[i], f) for i, f in enumerate(made)}
            again = tuple(f for f in made if f in done)  # the seam pass makes frames a second time
            done.update(made)
            self.emit(FramesReady(window=index, frames=frames, level=window.level, mode=window.mode, seconds=time.perf_counter() - self.started,
                                  replaces=again, window_done=part == len(chunks) - 1))
        self.job.stats["encode_seconds"] = self.encoder.seconds

