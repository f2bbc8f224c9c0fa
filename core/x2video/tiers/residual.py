"""Tier 1, the residual: one deterministic pass of the tier-1 net (`x2video.model.residual`) over the formula.

It adds what albedo x irradiance misses and its channels show: the glossy term, metals, emitters, windows (docs/ARCHITECTURE.md,
"Path-traced ground truth"); per frame, so it cannot flicker. Large frames run the net at a working size
(`RenderSettings.residual_pixels`) and bring its log-space correction back onto the full-resolution formula.
"""
from __future__ import annotations

import logging
from typing import Sequence

import numpy as np
import torch

from x2video.conditioning.frame import FrameConditioning
from x2video.conditioning.network import downsample_conditioning, onto_formula, working_size
from x2video.model.api import RenderModel
from x2video.render.settings import RenderSettings
from x2video.tiers.base import PerFrameTier, RenderJob
from x2video.tiers.regions import feathered

log = logging.getLogger(__name__)


class ResidualTier(PerFrameTier):
    """Tier 1: `residual_frames` of every frame, with the model's tier-1 net."""

    name = "residual"
    glossy = True

    def available(self, model: RenderModel | None) -> str | None:
        if model is None or model.residual_net is None:
            return ("quality 'residual' needs the tier-1 network (residual.safetensors beside the weights);"
                    " the loaded model has none")
        return None

    def working_size(self, size: tuple[int, int], settings: RenderSettings, model: RenderModel | None) -> tuple[int, int] | None:
        assert model is not None and model.residual_net is not None
        return working_size(size, model.residual_net.cfg.factor, settings.residual_pixels)

    def begin(self, job: RenderJob) -> None:
        work = self.working_size(job.shot.size, job.settings, job.model)
        if work is not None:
            log.info("shot size %dx%d: the tier-1 net runs at %dx%d (residual_pixels %d), its correction of the formula brought"
                     " back on the full-resolution formula", job.shot.size[1], job.shot.size[0], work[1], work[0], job.settings.residual_pixels)

    def frames(self, job: RenderJob, conds: Sequence[FrameConditioning]) -> list[np.ndarray]:
        assert job.model is not None
        with job.clock.stage("residual"):
            return residual_frames(job.model.residual_net, conds, job.model.device, self.batch, job.settings.guess_unseen,
                                   job.settings.residual_pixels, plausible=job.settings.quality == "auto")

    def glossy_frames(self, job: RenderJob, edited: FrameConditioning, original: FrameConditioning,
                      wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The net on the box around `wanted` only (`x2video.base.tier1`: equal to the whole frame inside it), the
        original frame's part kept in the Renderer's cache where it keeps what it made (`Renderer.retain`: the editor's
        live preview runs the net once per frame of a slider drag). The net is the model's difference net where it has
        one (`x2video train difference`: fitted to edits' differences), else the tier-1 net; the difference net's frames
        are its residual over the formula, R - F, inside `wanted` (0 elsewhere; `learned_difference`)."""
        from x2video.base.tier1 import residual_difference, residual_over_formula

        assert job.model is not None
        net = getattr(job.model, "difference_net", None)
        run = residual_difference if net is None else residual_over_formula
        with job.clock.stage("residual"):
            return run(job.model.residual_net if net is None else net, original, edited, wanted, cache=job.cache if job.retain else None,
                       device=job.model.device, guess_unseen=job.settings.guess_unseen, max_pixels=job.settings.residual_pixels)

    def learned_difference(self, job: RenderJob) -> bool:
        return getattr(job.model, "difference_net", None) is not None


@torch.inference_mode()
def residual_frames(net, conds: Sequence[FrameConditioning], device: torch.device | str = "cpu", batch: int = 4,
                    guess_unseen: bool = False, max_pixels: int = 0, plausible: bool = False) -> list[np.ndarray]:
    """Tier 1: (H, W, 3) linear frames from the tier-1 net, up to `batch` frames per pass and never more than
    `residual.MAX_PIXELS` pixels in one: a frame larger than that runs in overlapping tiles (`residual.apply_tiled`,
    equal to the whole-frame pass to float precision), so the net's working memory does not grow with the frame.
    A frame with more than `max_pixels` pixels (`RenderSettings.residual_pixels`; 0: none) runs the net at a
    working size of at most that many (`working.working_size`, channels area-averaged); the net's log-space
    correction of the formula there (`residual.correction`) comes back to full size bilinearly and is added to
    the full-resolution formula in log space, so the formula's detail stays full resolution.
    Unless `guess_unseen`, pixels whose channels say nothing of their light (`residual.unseen_light`: sky, clear
    glass, mirrors) keep the formula instead of the net's guess (decided at full resolution; at a working size the
    correction is also 0 on such working pixels and next to them, so the guess does not spread when upsampled).
    With `plausible` (quality 'auto'), the formula on a frame whose input is not of the kind the net was trained on
    (`x2video.model.plausible.out_of_range`: the net is not run on it), and wherever the net's correction of it is
    larger than the bounds chosen on validation rooms (`x2video.model.plausible.guard`): auto's promise never to render below
    the formula."""
    from x2video.formula import formula
    from x2video.model.plausible import out_of_range

    frames: list[np.ndarray] = [np.empty(0)] * len(conds)
    run = []  # the frames the net runs on
    for i, c in enumerate(conds):
        why = out_of_range(c.channels) if plausible else None
        if why is None:
            run.append(i)
        else:
            log.warning("tier 1 keeps the formula on this frame: %s (not the input it was trained on)", why)
            frames[i] = formula(c.channels, _shape(c))
    sizes = {i: working_size(_size(conds[i]), net.cfg.factor, max_pixels) if max_pixels else None for i in run}
    whole = [i for i in run if sizes[i] is None]
    for i, f in zip(whole, _net_frames(net, [conds[i] for i in whole], device, batch)):
        frames[i] = f
    small = [i for i in run if sizes[i] is not None]
    lows = [downsample_conditioning(conds[i], sizes[i]) for i in small]
    for i, low, r in zip(small, lows, _net_frames(net, lows, device, batch, corrections=True)):
        if not guess_unseen:  # upsampled, the guess would spread a working pixel onto the lit surfaces around
            r = _without_unseen(r, low)  # windows and mirrors (a bright rim): no correction there or next to it
        frames[i] = onto_formula(r, formula(conds[i].channels, _shape(conds[i])))
    for i in run:
        if not guess_unseen:
            frames[i] = keep_formula_where_unseen(frames[i], conds[i].channels)
        if plausible:
            frames[i] = _plausible(frames[i], conds[i])
    return frames


def _plausible(frame: np.ndarray, c: FrameConditioning) -> np.ndarray:
    """`frame` with the formula where tier 1's correction of it is implausible (`plausible.guard`), said in the log."""
    from x2video.formula import formula
    from x2video.model.plausible import guard

    out, verdict = guard(frame, formula(c.channels, _shape(c)))
    if verdict.engaged:
        log.warning("tier 1's correction of the formula is larger than the bounds chosen on validation rooms: %s", verdict.describe())
    return out


def _without_unseen(r: np.ndarray, low: FrameConditioning) -> np.ndarray:
    """A working-size correction `r` (h, w, 3) set to 0 where `low`'s channels hold no light and one pixel around."""
    import cv2

    from x2video.model.residual import unseen_light

    m = unseen_light(low.channels, r.shape[:2])
    if m is None or not m.any():
        return r
    near = cv2.dilate(m.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return np.where(near[..., None], 0, r).astype(np.float32)


def _shape(c: FrameConditioning) -> tuple[int, int] | None:
    return tuple(np.shape(c.amr_mask)[:2]) if np.size(c.amr_mask) else None  # type: ignore[return-value]


def _size(c: FrameConditioning) -> tuple[int, int]:
    return _shape(c) or next(np.shape(v)[:2] for v in c.channels.values() if v is not None)


def _net_frames(net, conds: Sequence[FrameConditioning], device: torch.device | str, batch: int,
                corrections: bool = False) -> list[np.ndarray]:
    """The net's own output for each frame (`residual_frames` without the unseen-light rule), or with `corrections`
    its log-space correction of the formula (before the output is clipped at 0)."""
    from x2video.formula import formula
    from x2video.model.residual import MAX_PIXELS, apply, apply_tiled, correction, features, needs_tiles, view_args

    shape, size = _shape, _size
    out: list[np.ndarray] = []
    i = 0
    while i < len(conds):
        hw = size(conds[i])
        if needs_tiles(hw, net.cfg.factor):
            view = view_args(net, conds[i].depth_source, conds[i].fov_y_deg)
            f = apply_tiled(net, conds[i].channels, shape(conds[i]), depth=view.get("depth"), fov_y_deg=view.get("fov_y_deg"))
            if corrections:  # (a working size beyond one tile: the clipped output's correction)
                f = np.log1p(np.maximum(f, 0)) - np.log1p(np.maximum(formula(conds[i].channels, shape(conds[i])), 0))
            out.append(f)
            i += 1
            continue
        n = max(1, min(batch, MAX_PIXELS // (hw[0] * hw[1])))
        group = [conds[i]]
        while len(group) < n and i + len(group) < len(conds) and size(conds[i + len(group)]) == hw:
            group.append(conds[i + len(group)])
        feats = [features(c.channels, shape(c), **view_args(net, c.depth_source, c.fov_y_deg)) for c in group]
        x = torch.from_numpy(np.stack([f[0] for f in feats])).to(device)  # (B, C_in, H, W)
        s = torch.from_numpy(np.stack([f[1] for f in feats])).to(device)  # (B, 3, H, W)
        y = (correction(net, x) if corrections else apply(net, x, s)).permute(0, 2, 3, 1).float().cpu().numpy()  # (B, H, W, 3)
        out.extend(np.ascontiguousarray(f) for f in y)
        i += len(group)
    return out


def keep_formula_where_unseen(frame: np.ndarray, channels, px: float = 2.0) -> np.ndarray:
    """`frame` (H, W, 3, a tier-1 render) with the formula where `residual.unseen_light` says the channels hold
    nothing of the light, blended over `px` pixels beyond (`feathered`), so the net's halo at the edge goes too."""
    from x2video.formula import formula
    from x2video.model.residual import unseen_light

    m = unseen_light(channels, frame.shape[:2])
    if m is None or not m.any():
        return frame
    w = feathered(m, px)[..., None]
    return (w * formula(channels, frame.shape[:2]) + (1 - w) * frame).astype(np.float32)
