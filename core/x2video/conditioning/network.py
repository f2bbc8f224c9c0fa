"""`NetworkConditioning`: what the diffusion network sees of a render's frames, and at which size, settled once per render.

Made once, before the first window (`for_model`: like a scheduler's `set_timesteps`), then used for every frame
(`frame`: like its `step`) and to bring each decoded frame back to the shot's size (`output`):

    net = NetworkConditioning.for_model(shot.size, conditioning, model.downsample, settings.working_pixels, reference)
    cond = net.frame(t)                  # frame t as the network runs it
    image = net.output(decoded, t)       # (H, W, 3) at the shot's size

Frames with more pixels than `working_pixels` run at a working resolution (their residual over the formula comes
back on the full-resolution formula: `x2video.conditioning.network`); others are reflect-padded to the model's factor
and cropped back.

Working resolution. The diffusion model is trained on small frames (the shipped one at 160x112) and its attention grows with
the square of the latent's pixels, so a 1920x1080 frame cannot run through it as a whole. Frames with
more pixels than `RenderSettings.working_pixels` run at a working resolution of at most that many pixels
(aspect kept, multiples of the model's factor; `working_size`), their channels, masks and reference
area-averaged down (`downsample_conditioning`). What comes back up is the network's *residual over the
formula*, not its frame:

    r_w    = log1p(D_w) - log1p(area(F))          at working size (D_w: the decoded frame)
    r      = upsample(r_w)                         at full size (bilinear)
    output = expm1(log1p(F) + r)                   F: albedo x irradiance at full resolution

so the formula's detail (texture, shadow edges) is always full resolution and the network adds only
what the formula misses, at the scale it can see it: the full-resolution channels guide the result
through the formula (a quotient image: output = F x exp(r), roughly). The residual itself is upsampled
bilinearly. A guided filter on top (He et al. 2013, joint upsampling; OpenCV's
`cv2.ximgproc.guidedFilter` guided by log1p(F)) measured worse: with a perfect network (the
path-traced ground truth area-averaged to the working size) on a 1024x1024 Cycles frame at 264x264,
bilinear log residual 34.9 dB; guided (eps 1e-2) radius 1 34.4, radius 4 (one working pixel, what
`upsample="guided"` uses) 31.8, radius 8 29.5; the network's frame upsampled alone 33.9; the formula
17.8. `python -m bench.bigframes --data ...` measures this ceiling on every shot (`bench.bigframes.ceiling`);
`to_full(..., upsample="guided")` keeps the alternative.
Where the formula is zero (a dropped channel, an A|M|R region) the expression reduces to the network's
own frame upsampled.
"""
from __future__ import annotations

import dataclasses
import functools
import logging
import math
from dataclasses import dataclass

import numpy as np

from x2video.conditioning.frame import Conditioning, FrameConditioning
from x2video.formula import formula_frame

log = logging.getLogger(__name__)


def working_size(size: tuple[int, int], factor: int, max_pixels: int) -> tuple[int, int] | None:
    """(h, w) to run the network at for frames of `size` (H, W), or None to run at full size (reflect-padded):
    None when `max_pixels` is 0 or the padded frame has no more pixels than it; else the largest size of at
    most `max_pixels` pixels with the frame's aspect ratio and both sides multiples of `factor`."""
    h, w = size
    if max_pixels <= 0 or (h + (-h) % factor) * (w + (-w) % factor) <= max_pixels:
        return None
    s = math.sqrt(max_pixels / (h * w))
    wh = max(factor, int(h * s) // factor * factor)
    ww = max(factor, int(w * s) // factor * factor)
    return wh, ww


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


def resize_area(a: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W, ...) float32 area-averaged to (h, w, ...) (OpenCV INTER_AREA; any number of trailing channels)."""
    import cv2

    a = np.asarray(a, np.float32)
    h, w = size
    if a.shape[:2] == (h, w):
        return a
    flat = a.reshape(a.shape[0], a.shape[1], -1)
    out = np.stack([cv2.resize(flat[..., i], (w, h), interpolation=cv2.INTER_AREA) for i in range(flat.shape[-1])], -1)
    return out.reshape(h, w, *a.shape[2:])


def _normals(n: np.ndarray) -> np.ndarray:
    """Area-averaged normals back to unit length where the pixel is mostly geometry (|n| > 0.5), 0 elsewhere
    (the channel's convention for no geometry, e.g. a window)."""
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where(length > 0.5, n / np.maximum(length, 1e-6), 0).astype(np.float32)


def downsample_conditioning(cond: FrameConditioning, size: tuple[int, int]) -> FrameConditioning:
    """`cond` at working size (h, w): channels and masks area-averaged (radiometric channels keep their mean),
    normals renormalised (`_normals`)."""
    channels = {}
    for k, v in cond.channels.items():
        if v is None:
            channels[k] = None
            continue
        small = resize_area(v, size)
        channels[k] = _normals(small) if k == "normal" else small
    masks = np.asarray(cond.local_masks, np.float32)
    return dataclasses.replace(
        cond,
        channels=channels,
        amr_mask=resize_area(cond.amr_mask, size),
        local_masks=np.stack([resize_area(m, size) for m in masks]) if masks.shape[0] else np.zeros((0, *size), np.float32),
        depth_source=None if cond.depth_source is None else functools.partial(_depth_at, cond.depth_source, size),
        prior=None,  # tier 1's frame of the full-size channels; remade at this size when needed
    )


def _depth_at(source, size: tuple[int, int]) -> np.ndarray:
    """A frame's depth at working size (h, w): nearest samples (an average across an edge is a depth nowhere)."""
    import cv2

    d = np.asarray(source(), np.float32)
    return cv2.resize(d.reshape(d.shape[:2]), (size[1], size[0]), interpolation=cv2.INTER_NEAREST)[..., None]


def guide_image(cond: FrameConditioning, base: np.ndarray) -> np.ndarray | None:
    """(H, W, 3) full-resolution guide for `upsample="guided"`: log1p of the formula `base` where it is not all
    zero, else the albedo, else the normal (mapped to [0, 1]); None when there is nothing to guide by."""
    if np.any(base > 0):
        return np.log1p(np.maximum(base, 0)).astype(np.float32)
    al, nr = cond.channels.get("albedo"), cond.channels.get("normal")
    if al is not None:
        return np.clip(np.asarray(al, np.float32)[..., :3], 0, 1)
    if nr is not None:
        return (0.5 * np.asarray(nr, np.float32)[..., :3] + 0.5).astype(np.float32)
    return None


#: ways `to_full` brings the residual up: plain bilinear (the default, measured best), or that followed by the guided filter
UPSAMPLE = ("bilinear", "guided")


def guided_upsample(low: np.ndarray, guide: np.ndarray, radius: int | None = None, eps: float = 1e-2) -> np.ndarray:
    """(H, W, C) from (h, w, C) `low`: bilinear upsampling, then the guided filter of that by the full-resolution
    `guide` (H, W, 3); `radius` in full-resolution pixels, default one working pixel."""
    import cv2

    H, W = guide.shape[:2]
    up = cv2.resize(np.asarray(low, np.float32), (W, H), interpolation=cv2.INTER_LINEAR).reshape(H, W, -1)
    radius = radius or max(1, int(round(max(H / low.shape[0], W / low.shape[1]))))
    return cv2.ximgproc.guidedFilter(np.ascontiguousarray(guide, np.float32), up, radius, eps, -1).reshape(H, W, -1)


def to_full(frame: np.ndarray, cond_full: FrameConditioning, upsample: str = "bilinear") -> np.ndarray:
    """(H, W, 3) full-resolution linear frame from a diffusion frame (h, w, 3) made at working size for the frame
    whose full-resolution conditioning is `cond_full` (see the module docstring)."""
    if upsample not in UPSAMPLE:
        raise ValueError(f"unknown upsampling {upsample!r} (use one of {', '.join(UPSAMPLE)})")
    base = formula_frame(cond_full)  # (H, W, 3) albedo x irradiance, zero inside A|M|R regions
    h, w = frame.shape[:2]
    r = np.log1p(np.maximum(frame, 0)) - np.log1p(np.maximum(resize_area(base, (h, w)), 0))  # (h, w, 3) what the network adds
    return onto_formula(r, base, guide_image(cond_full, base) if upsample == "guided" else None)


def onto_formula(r: np.ndarray, base: np.ndarray, guide: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) linear: a working-size log-space residual `r` (h, w, 3) upsampled (bilinear; then the guided filter
    by `guide` when one is given) and added to log1p of the full-resolution formula `base` (H, W, 3). The
    diffusion tier's `to_full` and tier 1's working size (`x2video.tiers.residual.residual_frames`) both end here."""
    import cv2

    H, W = base.shape[:2]
    r = np.ascontiguousarray(r, np.float32)
    up = guided_upsample(r, guide) if guide is not None else cv2.resize(r, (W, H), interpolation=cv2.INTER_LINEAR).reshape(H, W, 3)
    return np.maximum(np.expm1(np.log1p(np.maximum(base, 0)) + up), 0).astype(np.float32)


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
        elif ph or pw:
            log.info("shot size %dx%d: reflect-padded to %dx%d (the model's factor %d), frames cropped back",
                     width, height, width + pw, height + ph, factor)
        net = cls(full, (height, width), work, (ph, pw))
        return net if reference is None else dataclasses.replace(net, reference=(reference[0], net.image(reference[1])))

    def image(self, rgb: np.ndarray) -> np.ndarray:
        """An (H, W, 3) image at the shot's size (a reference: the user's, or a path-traced keyframe) as the network
        reads it: area-averaged to the working size, or reflect-padded to the model's factor."""
        if self.work is not None:
            return resize_area(rgb, self.work)
        return pad_image(rgb, *self.pad)

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
