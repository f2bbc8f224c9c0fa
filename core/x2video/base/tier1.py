"""Tier 1's difference inside an edit's reach (issue 52): the tier-1 net runs on the box around what an edit changed,
not on the whole frame, and what it made of the original frame is kept for the next frame of a live preview.

An edit over the base needs R(edited) - R(original) only where it reaches (`x2video.base.difference`). The net's output
at a pixel depends on the features within its receptive radius (`residual.receptive_radius`, 58 pixels) and, through
its global context, on the mean of the frame's bottom features. So the box (`part_box`) holds the wanted pixels grown
by that radius and the changed pixels grown by a bottom cell's view (67 pixels): every bottom cell that differs between
the edited and the original frame lies inside the box, and none of those sees its edge. Both boxes run with the
original frame's bottom features outside the box for the rest of the global context (`ResidualNet.forward_part`):
inside the wanted pixels each equals a whole-frame pass to float precision for any weights (tests/test_base_tier1.py),
and their difference cancels what the box's edges do to both. Where the net cannot run on a box (screen-space hints,
a working size, tiles: `supports_parts`) both frames are the whole-frame pass, as before.

The original frame's whole-frame bottom sum and its box's frame do not change while a slider moves: they stay in the
Renderer's cache (`x2video.conditioning.cache`, under the frame's channels, compared on each use), so each frame of a
drag runs the net once, on the box. The editor's live preview and a render run this same code: the preview's frame is
the render's.
"""
from __future__ import annotations

import secrets
import weakref
from typing import Mapping

import numpy as np
import torch

from x2video.base.difference import changed
from x2video.conditioning.frame import FrameConditioning

#: (y0, y1, x0, x1) of a box on the frame padded to the net's factor (`correction` pads at the bottom and right)
Box = tuple[int, int, int, int]

_NET_KEYS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def part_box(wanted: np.ndarray, changed: np.ndarray, factor: int, radius: int, span: int) -> Box | None:
    """The box of an (H, W) frame padded to `factor` that holds `wanted` grown by `radius` and `changed` grown by
    `span` (pixels), on the factor grid and inside the padded frame; None when nothing is wanted."""
    if not wanted.any():
        return None
    h, w = wanted.shape
    H, W = h + (-h) % factor, w + (-w) % factor
    bounds = [_bounds(wanted, radius)] + ([_bounds(changed, span)] if changed.any() else [])
    y0, x0 = min(b[0] for b in bounds), min(b[2] for b in bounds)
    y1, x1 = max(b[1] for b in bounds), max(b[3] for b in bounds)
    return (max(0, y0 // factor * factor), min(H, -(-y1 // factor) * factor),
            max(0, x0 // factor * factor), min(W, -(-x1 // factor) * factor))


def _bounds(mask: np.ndarray, grow: int) -> Box:
    ys, xs = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    return int(ys[0]) - grow, int(ys[-1]) + 1 + grow, int(xs[0]) - grow, int(xs[-1]) + 1 + grow


def supports_parts(net, size: tuple[int, int], max_pixels: int = 0) -> bool:
    """Whether `residual_difference` runs `net` on a box of frames of `size` (H, W): not for a net with screen-space
    hints (they march rays across the frame), nor where the frame runs at a working size (`max_pixels`) or in tiles."""
    from x2video.conditioning.network import working_size
    from x2video.model.residual import needs_tiles

    f = net.cfg.factor
    return hasattr(net, "forward_part") and not net.cfg.hints and not (max_pixels and working_size(size, f, max_pixels)) and not needs_tiles(size, f)


@torch.inference_mode()
def residual_difference(net, original: FrameConditioning, edited: FrameConditioning, wanted: np.ndarray, *, cache=None,
                        device: torch.device | str = "cpu", guess_unseen: bool = False,
                        max_pixels: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Tier 1's frames of `edited` and `original` (H, W, 3, float32; `residual.residual_frames`'), equal to a
    whole-frame pass inside `wanted` (H, W) bool to float precision; outside the box (`part_box`) they are 0.
    `cache`: a `ConditioningCache` that keeps the original's part between calls (None: computed each time). Where the
    net cannot run on a box (`supports_parts`), both frames are the whole-frame pass."""
    from x2video.model.residual import receptive_radius
    from x2video.tiers.residual import residual_frames

    h, w = edited.size
    if not supports_parts(net, (h, w), max_pixels):
        r_e, r_o = residual_frames(net, [edited, original], device, 2, guess_unseen, max_pixels)
        return r_e, r_o
    f = net.cfg.factor
    radius, span = receptive_radius(net.cfg)
    H, W = h + (-h) % f, w + (-w) % f
    box = part_box(wanted, np.zeros_like(wanted), f, radius, span)
    if box is not None and box != (0, H, 0, W):  # what changed may widen it (not past the whole frame: skip looking)
        box = part_box(wanted, changed(original, edited), f, radius, span)
    if box is None:
        return np.zeros((h, w, 3), np.float32), np.zeros((h, w, 3), np.float32)
    cells = torch.tensor([[(H // f) * (W // f)]], dtype=torch.float32, device=device)  # (1, 1)
    pad_o, pad_e = _padded(original.channels, f), _padded(edited.channels, f)
    key = None if cache is None else _key(net, original, cache)
    part_key = None if key is None else f"{key}:{box}"
    kept = None if part_key is None else cache.get(f"{part_key}:frame")
    others = None if part_key is None else cache.get(f"{part_key}:others")
    if kept is None or others is None:
        x_o, s_o = _features(pad_o, box, device)
        if box == (0, H, 0, W):  # the whole frame: nothing outside
            others = torch.zeros(1, net.cfg.widths[-1], device=device)
        else:  # (1, C): the original's bottom features outside the box, its whole frame's (kept per frame) less the box's
            total = None if key is None else cache.get(f"{key}:sum")
            if total is None:
                total = net.bottom(_features(pad_o, (0, H, 0, W), device)[0]).double().sum((0, 2, 3))
                if key is not None:
                    cache.put(f"{key}:sum", total)
            others = (total - net.bottom(x_o).double().sum((0, 2, 3))).float()[None]
        d_o, _ = net.forward_part(x_o, others, cells)
        kept = torch.from_numpy(_frame(d_o, s_o, box, original.channels, (h, w), guess_unseen))
        if part_key is not None:
            cache.put(f"{part_key}:frame", kept)
            cache.put(f"{part_key}:others", others)
    x_e, s_e = _features(pad_e, box, device)
    d_e, _ = net.forward_part(x_e, others, cells)
    r_e = _frame(d_e, s_e, box, edited.channels, (h, w), guess_unseen)
    return _placed(r_e, box, (h, w)), _placed(kept.numpy(), box, (h, w))


def residual_over_formula(net, original: FrameConditioning, edited: FrameConditioning, wanted: np.ndarray,
                          **kw) -> tuple[np.ndarray, np.ndarray]:
    """A difference net's frames of `edited` and `original`: `residual_difference`'s less the formula under them
    (albedo x irradiance), inside `wanted` (0 elsewhere): what `x2video.base.stage.edited_frame` adds to tier 0's rebuild
    (`learned`), as `x2video.train.difference_stage` trains it."""
    from x2video.formula import formula

    r_e, r_o = residual_difference(net, original, edited, wanted, **kw)
    out_e, out_o = np.zeros_like(r_e), np.zeros_like(r_o)
    if not wanted.any():
        return out_e, out_o
    y0, y1, x0, x1 = _bounds(wanted, 0)  # the formula on the box of `wanted` only (a slider drag runs this every frame)
    rows, cols = slice(y0, y1), slice(x0, x1)
    w = wanted[rows, cols, None]
    for out, r, cond in ((out_e, r_e, edited), (out_o, r_o, original)):
        box = cond.cropped(rows, cols)
        out[rows, cols] = np.where(w, r[rows, cols] - formula(box.channels, box.size), 0)
    return out_e, out_o


def _key(net, original: FrameConditioning, cache) -> str | None:
    """What `cache` knows the original frame's parts by: the net's weights, the frame's index and size, and a generation
    that changes whenever the frame's channels do, checked against a copy of them kept in the cache (a comparison costs
    a tenth of hashing the 3 MB of a 320x224 frame, once per frame of a drag). None: a net whose weights cannot be read."""
    from x2video.channels import INTRINSIC
    from x2video.model.residual_engine import weights_sha

    sha = _NET_KEYS.get(net)
    if sha is None:
        try:
            sha = _NET_KEYS[net] = weights_sha(net)
        except TypeError:
            return None
    names = [n for n in INTRINSIC if original.channels.get(n) is not None]
    h, w = original.size
    prefix = f"tier1-part:{sha}:{original.frame_index}:{h}x{w}:{'+'.join(names)}"
    generation = cache.get(f"{prefix}:generation")
    if generation is not None and all(_same(cache.get(f"{prefix}:{n}"), original.channels[n]) for n in names):
        return f"{prefix}:{int(generation)}"
    generation = secrets.randbits(62)
    for n in names:
        cache.put(f"{prefix}:{n}", torch.from_numpy(np.array(original.channels[n], copy=True)))
    cache.put(f"{prefix}:generation", torch.tensor(generation))
    return f"{prefix}:{generation}"


def _same(kept: torch.Tensor | None, v) -> bool:
    """Whether `kept` holds the values of `v` (NaN equal to NaN)."""
    if kept is None:
        return False
    a, b = kept.numpy(), np.asarray(v)
    return a.shape == b.shape and (np.array_equal(a, b) or np.array_equal(a, b, equal_nan=True))


def _padded(ch: Mapping[str, np.ndarray | None], factor: int) -> dict[str, np.ndarray | None]:
    """The channels padded at the bottom and right to the net's factor as `residual.correction` pads the features."""
    from x2video.formula import frame_shape
    from x2video.model.residual import _pad_channel

    h, w = frame_shape(ch, None)
    ph, pw = (-h) % factor, (-w) % factor
    return {k: None if v is None else _pad_channel(np.asarray(v), ph, pw) for k, v in ch.items()}


def _features(padded: Mapping[str, np.ndarray | None], box: Box, device: torch.device | str) -> tuple[torch.Tensor, torch.Tensor]:
    """(1, C_in, h, w) features and (1, 3, h, w) formula of the box (both per pixel: those of the cropped channels)."""
    from x2video.model.residual import features

    y0, y1, x0, x1 = box
    x, s = features({k: None if v is None else v[y0:y1, x0:x1] for k, v in padded.items()}, (y1 - y0, x1 - x0))
    return torch.from_numpy(x)[None].to(device), torch.from_numpy(s)[None].to(device)


def _frame(delta: torch.Tensor, shading: torch.Tensor, box: Box, channels: Mapping[str, np.ndarray | None],
           size: tuple[int, int], guess_unseen: bool) -> np.ndarray:
    """The box's frame (bh, bw, 3) inside the real frame from the net's log-space `delta` and the formula `shading`
    (1, 3, by, bx each): `residual.apply`'s, and unless `guess_unseen` the formula where the channels hold no light
    (`residual.keep_formula_where_unseen`, its mask made on the whole frame: it reads the frame's light level)."""
    from x2video.model.residual import unseen_light
    from x2video.tiers.regions import feathered

    y0, y1, x0, x1 = box
    bh, bw = min(y1, size[0]) - y0, min(x1, size[1]) - x0
    base = shading[0, :, :bh, :bw]
    out = torch.expm1(torch.log1p(base.clamp_min(0)) + delta[0, :, :bh, :bw]).clamp_min(0)  # (3, bh, bw), as `apply`
    out, base = out.permute(1, 2, 0).float().cpu().numpy(), base.permute(1, 2, 0).cpu().numpy()
    if guess_unseen:
        return np.ascontiguousarray(out)
    m = unseen_light(channels, size)
    if m is None or not m[y0:y0 + bh, x0:x0 + bw].any():
        return np.ascontiguousarray(out)
    wt = feathered(m[y0:y0 + bh, x0:x0 + bw], 2.0)[..., None]
    return (wt * base + (1 - wt) * out).astype(np.float32)


def _placed(part: np.ndarray, box: Box, size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) float32: `part` at the box, 0 elsewhere."""
    out = np.zeros((*size, 3), np.float32)
    y0, _, x0, _ = box
    out[y0:y0 + part.shape[0], x0:x0 + part.shape[1]] = part
    return out


__all__ = ["Box", "part_box", "residual_difference", "residual_over_formula", "supports_parts"]
