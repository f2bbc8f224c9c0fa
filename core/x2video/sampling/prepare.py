"""`Renderer.prepare`: what a diffusion render of a shot would compute before its first keyframe, done ahead of it.

Each frame's conditioning latents (and the shading detail residual models add back) go into the Renderer's
content-keyed cache in the order the render reads them, the first keyframe window first; the engine's graphs
for the plan's UNet variants and the VAE decoder are built and run once (`x2video.model.engine`); the prompt
encoder is loaded. A render started afterwards, or while it runs (the render cancels it), finds that work
done: the editor calls it in a worker thread when a shot is opened, so the first network keyframe after
Render costs only its denoising steps and its decoding. Tiers 0 and 1 encode nothing, so there is nothing to
prepare for them.
"""
from __future__ import annotations

import functools
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
import torch

from x2video.conditioning import FrameConditioning
from x2video.model.api import WindowInputs
from x2video.sampling import tiers
from x2video.sampling.cache import conditioning_key
from x2video.sampling.events import CancelToken, RenderSettings

if TYPE_CHECKING:
    from x2video.sampling.renderer import Renderer
    from x2video.shot import Shot

log = logging.getLogger(__name__)


def prepare(renderer: "Renderer", shot: "Shot", settings: RenderSettings, edits: Any = None, cancel: CancelToken | None = None, *,
            base_dir: str | Path | None = None) -> int:
    """See the module docstring; returns how many frames were encoded now (0 when the cache had them all,
    the tier needs no encoding, or `cancel` was set before any)."""
    from x2video.sampling.renderer import pad_amounts, pad_conditioning, plain_conditioning

    model = renderer.model
    net = getattr(model, "residual_net", None)
    reasons, only_regions = tiers.generation_reasons(shot, edits)
    choice = tiers.choose_tier(settings.quality, reasons, only_regions, net is not None, "" if edits is None else edits.global_prompt,
                               residual_trusted=bool(getattr(model, "residual_auto", True)))
    if choice.tier != "diffusion":
        return 0
    t0 = time.perf_counter()
    if edits is None:
        conditioning: Callable[[int], FrameConditioning] = functools.partial(plain_conditioning, shot)
    else:
        from x2video.edits import apply_edits

        conditioning = functools.partial(apply_edits, shot, edits)
    ph, pw = pad_amounts(shot.size, model.downsample)
    if ph or pw:
        unpadded = conditioning
        conditioning = lambda t: pad_conditioning(unpadded(t), ph, pw)  # noqa: E731
    settings = renderer._validate(shot, settings)
    renderer._use_engine(settings)
    windows = renderer.plan(shot, settings)
    text = model.encode_prompts([""]) if getattr(model, "text_encoder", None) is not None else None  # loads the text encoder
    model_key = model.content_key()
    warmed: set[tuple] = set()
    encoded = ready = 0
    with torch.inference_mode():
        for index, window in enumerate(windows):
            if cancel is not None and cancel.cancelled:
                break
            ready += 1
            conds = [conditioning(f) for f in window.frames]
            keys = [conditioning_key(c, model_key) for c in conds]
            before = renderer.cache.stats().entries
            cond = renderer._encode(conds, keys)  # (n, C_cond, h, w)
            if settings.detail:
                gen = list(window.generate_positions)
                renderer._detail([conds[p] for p in gen], [keys[p] for p in gen], cond[gen])
            encoded += max(0, renderer.cache.stats().entries - before)
            if text is not None and renderer.engine != "torch":
                _warm(model, window, cond, text, settings.sampler == "lcm", warmed, decode=index == 0)
    log.info("prepared %d of %d windows (%d frames encoded now, engine %s) in %.2f s", ready, len(windows),
             encoded, renderer.engine, time.perf_counter() - t0)
    return encoded


def _warm(model: Any, window: Any, cond: torch.Tensor, text: torch.Tensor, lcm: bool, warmed: set[tuple], decode: bool) -> None:
    """Build (export or load, compile) and run once the engine's graph of this window's UNet variant and, with
    `decode`, the decoder's, so the render's first call is not the one that pays for it."""
    from x2video.model.engine import unet_variant

    n, _, h, w = cond.shape
    variant = (lcm, unet_variant(window.mode, window.level, window.ref_positions, n, model.config.hybrid.interp_levels), h, w)
    if variant not in warmed:
        warmed.add(variant)
        z = torch.zeros(n, model.latent_channels, h, w, device=model.device, dtype=model.dtype)  # (n, 4, h, w)
        inputs = WindowInputs(cond=cond, ref=z, ref_positions=window.ref_positions, mode=window.mode, level=window.level,
                              text_global=text, text_local=text.new_zeros((0, *text.shape[1:])),
                              local_masks=torch.zeros(n, 0, *np.multiply((h, w), model.downsample)))
        model.predict_v(z, torch.tensor(999), inputs, lcm=lcm)
    if decode:
        model.decode(torch.zeros(1, model.latent_channels, h, w, device=model.device, dtype=model.dtype))
