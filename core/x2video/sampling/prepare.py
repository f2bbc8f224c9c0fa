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

import logging
import time
from typing import TYPE_CHECKING, Sequence

import torch

from x2video.model.api import WindowInputs
from x2video.sampling import setup
from x2video.sampling.cache import conditioning_key
from x2video.sampling.events import CancelToken
from x2video.sampling.planner import Window
from x2video.sampling.settings import RenderSettings
from x2video.sampling.tier_diffusion import DiffusionTier, diffusion_windows, reference_frame

if TYPE_CHECKING:
    from x2video.edits.model import Edits
    from x2video.sampling.renderer import Renderer
    from x2video.shot import Shot

log = logging.getLogger(__name__)


def prepare(renderer: Renderer, shot: Shot, settings: RenderSettings, edits: Edits | None = None, cancel: CancelToken | None = None) -> int:
    """See the module docstring; returns how many frames were encoded now (0 when the cache had them all,
    the tier needs no encoding, or `cancel` was set before any). The conditioning is the diffusion tier's own
    (`x2video.sampling.setup.network_frames`: padded, or at the working size for large frames)."""
    model = renderer.model
    choice = renderer.choose_tier(shot, edits, settings)
    if model is None or choice.tier != DiffusionTier.name:
        return 0
    t0 = time.perf_counter()
    conditioning = setup.network_frames(shot.size, setup.frame_conditioning(shot, edits), model.downsample, settings.working_pixels).conditioning
    settings = setup.resolve(settings, model)
    renderer.engine = setup.use_engine(model, settings.engine)
    windows = diffusion_windows(setup.frame_range(shot, settings), settings, reference_frame(edits))
    text = model.encode_prompts([""]) if model.text_encoder is not None else None  # loads the text encoder
    encoder = setup.Encoder(model, renderer.cache, renderer.clock)
    model_key = model.content_key()
    encoded = ready = 0
    with torch.inference_mode():
        for index, window in enumerate(windows):
            if cancel is not None and cancel.cancelled:
                break
            ready += 1
            conds = [conditioning(f) for f in window.frames]
            keys = [conditioning_key(c, model_key) for c in conds]
            before = renderer.cache.stats().entries
            cond = encoder.encode(conds, keys)  # (n, C_cond, h, w)
            if settings.detail:
                gen = list(window.generate_positions)
                encoder.detail([conds[p] for p in gen], [keys[p] for p in gen], cond[gen])
            encoded += max(0, renderer.cache.stats().entries - before)
            if index == 0 and text is not None:  # the first keyframe window is encoded: now every graph the render runs
                warm_engine(renderer, windows, settings, (cond.shape[-2], cond.shape[-1]), text, cancel)
    log.info("prepared %d of %d windows (%d frames encoded now, engine %s) in %.2f s", ready, len(windows),
             encoded, renderer.engine, time.perf_counter() - t0)
    return encoded


def warm_engine(renderer: Renderer, windows: Sequence[Window], settings: RenderSettings, latent_size: tuple[int, int],
                text: torch.Tensor | None = None, cancel: CancelToken | None = None) -> int:
    """Build (export or read from the disk cache, compile) and run once on zeros the engine's graph of every UNet
    variant `windows` use, in plan order and as many as the engine keeps at once (`engine.UNET_GRAPHS`: a long
    shot's later levels come back from the blob cache when reached), and the decoder's, so no render call pays
    for them; nothing for PyTorch. Returns the variants built. `settings` must be validated
    (`x2video.sampling.setup.resolve`: the sampler resolved)."""
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
