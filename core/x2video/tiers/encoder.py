"""`Encoder`: the conditioning latents and shading detail of frames, through the Renderer's content-keyed cache.

What the diffusion tier reads per window and `Renderer.prepare` computes ahead, encoded once per content
(paper Sec. Acceleration). A model that samples its residual over tier 1's frame gets that frame first (`with_priors`).
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Callable

import numpy as np
import torch

from x2video.conditioning.cache import ConditioningCache
from x2video.conditioning.frame import FrameConditioning
from x2video.model.shading import shading_available
from x2video.render.timing import NoTimes, StageTimes
from x2video.tiers.residual import residual_frames

if TYPE_CHECKING:
    from x2video.model.api import RenderModel


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
