"""What a render sets up before its first frame: the frames' conditioning, at the network's size, and the settings resolved.

One module for every tier and for `Renderer.prepare` (which encodes ahead what the diffusion tier will read),
so both build the same conditioning (the working-size branch included) and encode it through the same cache:

    conditioning = frame_conditioning(shot, edits)                 # frame -> edited FrameConditioning
    net = network_frames(shot.size, conditioning, model.downsample, settings.working_pixels, reference)
    settings = resolve(settings, model)                            # the preset resolved, every bound checked
    encoder = Encoder(model, cache, clock)                         # cached conditioning latents and detail

Paper Sec. Acceleration: each frame's conditioning is encoded once, through a content-keyed cache.
"""
from __future__ import annotations

import dataclasses
import functools
import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np
import torch

from x2video.channels import INTRINSIC
from x2video.conditioning import FrameConditioning, camera_view
from x2video.model.shading import shading_available
from x2video.sampling import working
from x2video.sampling.cache import ConditioningCache
from x2video.sampling.settings import RenderSettings
from x2video.sampling.tier_residual import residual_frames
from x2video.sampling.timing import NoTimes, StageTimes

if TYPE_CHECKING:
    from x2video.edits.model import Edits
    from x2video.model.api import RenderModel
    from x2video.shot import Shot

log = logging.getLogger(__name__)

#: frame index -> that frame's (edited) conditioning
Conditioning = Callable[[int], FrameConditioning]


def plain_conditioning(shot: Shot, t: int) -> FrameConditioning:
    """A frame's conditioning with no edits: the shot's channels, absent ones dropped, no masks."""
    h, w = shot.size
    channels: dict[str, np.ndarray | None] = {n: shot.channel(n, t) if shot.has(n) else None for n in INTRINSIC}
    return FrameConditioning(
        channels=channels,
        amr_mask=np.zeros((h, w), np.float32),
        local_masks=np.zeros((0, h, w), np.float32),
        frame_index=t,
        **camera_view(shot, t),
    )


def frame_conditioning(shot: Shot, edits: Edits | None) -> Conditioning:
    """frame -> its conditioning under `edits` (`x2video.edits.apply_edits`), or the plain channels when None."""
    if edits is None:
        return functools.partial(plain_conditioning, shot)
    from x2video.edits import apply_edits

    return functools.partial(apply_edits, shot, edits)


def frame_range(shot: Shot, settings: RenderSettings) -> tuple[int, int]:
    """[start, stop) of the shot a render with `settings` covers (`RenderSettings.frames`, default all)."""
    start, stop = settings.frames if settings.frames is not None else (0, shot.num_frames)
    if not 0 <= start < stop <= shot.num_frames:
        raise ValueError(f"frame range [{start}, {stop}) outside the shot's {shot.num_frames} frames")
    return start, stop


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
        prior=None,  # remade from the padded channels when needed
    )


@dataclass
class NetworkFrames:
    """The diffusion network's view of a shot: `conditioning` at the size it runs at, `work` the working size (None:
    full size, reflect-padded by `pad` to the model's factor) and the user's `reference` (frame, image) at that size."""

    conditioning: Conditioning
    work: tuple[int, int] | None
    pad: tuple[int, int]
    reference: tuple[int, np.ndarray] | None


def network_frames(size: tuple[int, int], conditioning: Conditioning, factor: int, working_pixels: int,
                   reference: tuple[int, np.ndarray] | None = None) -> NetworkFrames:
    """Frames of `size` (H, W) as the diffusion network runs them: large frames at a working resolution (their
    residual over the formula comes back on the full-resolution formula, `x2video.sampling.working`), others
    reflect-padded to the model's `factor` (decoded frames cropped back)."""
    height, width = size
    work = working.working_size((height, width), factor, working_pixels)
    ph, pw = (0, 0) if work is not None else pad_amounts((height, width), factor)
    full = conditioning
    if work is not None:
        log.info("shot size %dx%d: the diffusion network runs at %dx%d (working_pixels %d), its residual over the formula"
                 " brought back on the full-resolution formula", width, height, work[1], work[0], working_pixels)
        conditioning = lambda t: working.downsample_conditioning(full(t), work)  # noqa: E731
        if reference is not None:
            reference = (reference[0], working.resize_area(reference[1], work))
    elif ph or pw:
        log.info("shot size %dx%d: reflect-padded to %dx%d (the model's factor %d), frames cropped back",
                 width, height, width + pw, height + ph, factor)
        conditioning = lambda t: pad_conditioning(full(t), ph, pw)  # noqa: E731
        if reference is not None:
            reference = (reference[0], pad_image(reference[1], ph, pw))
    return NetworkFrames(conditioning, work, (ph, pw), reference)


def select_steps(settings: RenderSettings, model: RenderModel | None) -> RenderSettings:
    """Resolve `settings.preset` into a sampler and step count for this model.

    'fast': LCM-2 when the model has distilled (LCM) weights, else DDIM-4; 'quality': DDIM-20;
    None: the settings as given. `model` None (not built yet): as a model without LCM weights.
    """
    if settings.preset is None:
        return settings
    if settings.preset == "fast":
        sampler, steps = ("lcm", 2) if model is not None and model.has_lcm else ("ddim", 4)
    elif settings.preset == "quality":
        sampler, steps = "ddim", 20
    else:
        raise ValueError(f"unknown render preset {settings.preset!r} (use 'fast' or 'quality')")
    return dataclasses.replace(settings, sampler=sampler, steps=steps)


def check_pixel_bounds(settings: RenderSettings) -> None:
    for name in ("working_pixels", "residual_pixels"):
        if getattr(settings, name) < 0:
            raise ValueError(f"{name} must be 0 (full resolution) or more, got {getattr(settings, name)}")


def resolve(settings: RenderSettings, model: RenderModel | None) -> RenderSettings:
    """`settings` with the preset resolved for `model` (`select_steps`), every bound checked (ValueError names it)."""
    settings = select_steps(settings, model)
    if settings.sampler not in ("ddim", "lcm"):
        raise ValueError(f"unknown sampler {settings.sampler!r} (use 'ddim' or 'lcm')")
    if settings.sampler == "lcm" and model is not None and not model.has_lcm:
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
    check_pixel_bounds(settings)
    return settings


def use_engine(model: RenderModel, engine: str) -> str:
    """Point `model` at `engine` (`RenderSettings.engine`); returns what runs it ('torch' for a model without engines)."""
    return model.set_engine(engine)


class Encoder:
    """The conditioning latents and shading detail of frames, through a content-keyed cache: what the diffusion tier
    reads per window and `prepare` computes ahead. `seconds`: wall time spent encoding (0 when the cache held all)."""

    def __init__(self, model: RenderModel, cache: ConditioningCache, clock: StageTimes | NoTimes | None = None) -> None:
        self.model, self.cache = model, cache
        self.clock = clock if clock is not None else NoTimes()
        self.seconds = 0.0

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
            self.seconds += time.perf_counter() - t0
            made = {k: fresh[j].clone() for j, k in enumerate(missing)}
            for k, v in made.items():
                self.cache.put(k, v)
            found = [made[keys[i]] if v is None else v for i, v in enumerate(found)]
        return torch.stack(found)

    def with_priors(self, conds: list[FrameConditioning]) -> list[FrameConditioning]:
        """`conds`, each carrying tier 1's frame (`FrameConditioning.prior`) when the model samples its residual over it
        (`RenderModel.prior` "tier1"): `residual_frames` of the frames that lack one, with the model's own tier-1 net, as
        tier 1 renders them by default (the unseen-light rule included), so a zero residual renders exactly tier 1's frame.
        Filled in place: it is derived from the channels, like a cache."""
        if self.model.prior != "tier1":
            return conds
        todo = [c for c in conds if c.prior is None and shading_available(c.channels)]  # no albedo or irradiance: no prior
        if todo:
            if self.model.residual_net is None:
                raise ValueError("this model samples its residual over tier 1's frame (prior 'tier1') and has no tier-1 net")
            for c, f in zip(todo, residual_frames(self.model.residual_net, todo, self.model.device)):
                c.prior = f
        return conds

    def encode(self, conds: list[FrameConditioning], keys: list[str]) -> torch.Tensor:
        """(n, C_cond, h, w) conditioning latents, encoding only frames the cache lacks (one batch)."""
        with self.clock.stage("encode"):
            return self._cached(keys, lambda idx: self.model.encode_frames(self.with_priors([conds[i] for i in idx])))

    def detail(self, conds: list[FrameConditioning], keys: list[str], cond: torch.Tensor) -> np.ndarray | None:
        """(G, H, W, 3) `model.detail` of the generated frames, cached beside their conditioning latents in half
        precision (a full-resolution image per frame, twice its latents in float32: 1,000 frames at 320x224 hold
        0.4 GB instead of 0.8; EXR output is half float anyway), used in that precision on every render alike."""
        if not self.model.residual_prior:
            return None

        def compute(idx: list[int]) -> torch.Tensor:
            d = self.model.detail(self.with_priors([conds[i] for i in idx]), cond[idx])
            assert d is not None  # residual models always have a detail
            return torch.from_numpy(d).half()

        return self._cached([k + "#detail" for k in keys], compute).float().numpy()
