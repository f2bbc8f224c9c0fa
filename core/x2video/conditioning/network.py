"""`NetworkConditioning`: what the diffusion network sees of a render's frames, and at which size, settled once per render.

Made once, before the first window (`for_model`: like a scheduler's `set_timesteps`), then used for every frame
(`frame`: like its `step`) and to bring each decoded frame back to the shot's size (`output`):

    net = NetworkConditioning.for_model(shot.size, conditioning, model.downsample, settings.working_pixels, reference)
    cond = net.frame(t)                  # frame t as the network runs it
    image = net.output(decoded, t)       # (H, W, 3) at the shot's size

Frames with more pixels than `working_pixels` run at a working resolution (their residual over the formula comes
back on the full-resolution formula: `x2video.conditioning.working`); others are reflect-padded to the model's factor
and cropped back.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from x2video.conditioning.frame import Conditioning, FrameConditioning
from x2video.conditioning.working import downsample_conditioning, pad_amounts, pad_conditioning, pad_image, resize_area, to_full, working_size

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class NetworkConditioning:
    """The diffusion network's view of a shot: `full` (frame -> conditioning at the shot's `size` (H, W)), `work` the working
    size (None: full size, reflect-padded by `pad` to the model's factor) and the user's `reference` (frame, image) at the
    size the network runs at."""

    full: Conditioning
    size: tuple[int, int]
    work: tuple[int, int] | None
    pad: tuple[int, int]
    reference: tuple[int, np.ndarray] | None = None

    @classmethod
    def for_model(cls, size: tuple[int, int], full: Conditioning, factor: int, working_pixels: int,
                  reference: tuple[int, np.ndarray] | None = None) -> NetworkConditioning:
        """Frames of `size` (H, W) as a network of `factor` runs them with `working_pixels` (`RenderSettings.working_pixels`)."""
        height, width = size
        work = working_size((height, width), factor, working_pixels)
        ph, pw = (0, 0) if work is not None else pad_amounts((height, width), factor)
        if work is not None:
            log.info("shot size %dx%d: the diffusion network runs at %dx%d (working_pixels %d), its residual over the formula"
                     " brought back on the full-resolution formula", width, height, work[1], work[0], working_pixels)
            if reference is not None:
                reference = (reference[0], resize_area(reference[1], work))
        elif ph or pw:
            log.info("shot size %dx%d: reflect-padded to %dx%d (the model's factor %d), frames cropped back",
                     width, height, width + pw, height + ph, factor)
            if reference is not None:
                reference = (reference[0], pad_image(reference[1], ph, pw))
        return cls(full, (height, width), work, (ph, pw), reference)

    def frame(self, t: int) -> FrameConditioning:
        """Frame `t`'s conditioning at the size the network runs at."""
        if self.work is not None:
            return downsample_conditioning(self.full(t), self.work)
        return pad_conditioning(self.full(t), *self.pad)

    def output(self, image: np.ndarray, t: int) -> np.ndarray:
        """(H, W, 3) float32 frame `t` at the shot's size from the network's decoded `image` (at working size: its residual over
        the formula onto the full-resolution formula; padded: cropped back)."""
        if self.work is not None:
            return to_full(image, self.full(t))
        height, width = self.size
        return np.ascontiguousarray(image[:height, :width], dtype=np.float32)
