"""`apply_edits`: the pure function from (Shot, Edits, frame) to the model's `FrameConditioning`; and the user's reference image
at the shot's size (`resolve_reference`)."""
from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np

from x2video.channels import INTRINSIC
from x2video.conditioning.frame import Conditioning, FrameConditioning, camera_view, plain_conditioning, shot_passes
from x2video.edits.model import Edits
from x2video.edits.ops import MaskOut
from x2video.shot import Shot


def apply_edits(shot: Shot, edits: Edits, t: int) -> FrameConditioning:
    """The edited intrinsic channels of frame `t`, the A|M|R union mask and the local-prompt masks.

    Pure: reads the shot and the edits, modifies neither. Channels missing from the shot or in
    `edits.dropped` are None. Ops run in list order; `MaskOut` ops zero their channels inside
    the mask and add the region (mask > 0.5) to `amr_mask`. `local_masks` follow
    `edits.prompts().local`. The shot's passes (`FrameConditioning.passes`) are edited by the light operations
    as irradiance is (`Op.apply_passes`).
    """
    edits.validate()
    h, w = shot.size
    channels: dict[str, np.ndarray | None] = {
        n: (shot.channel(n, t) if shot.has(n) and n not in edits.dropped else None) for n in INTRINSIC
    }
    cache: dict[str, np.ndarray] = {}

    def mask(name: str | None) -> np.ndarray | None:
        if name is None:
            return None
        if name not in cache:
            cache[name] = edits.masks[name].at(shot, t)
        return cache[name]

    amr = np.zeros((h, w), np.float32)
    passes = shot_passes(shot, t)
    for op in edits.ops:
        m = mask(op.mask)
        op.apply(channels, m)
        op.apply_passes(passes, m)
        if isinstance(op, MaskOut) and m is not None:
            amr = np.maximum(amr, (m > 0.5).astype(np.float32))
    names = edits.local_prompt_masks()
    local = np.stack([mask(n) for n in names]) if names else np.zeros((0, h, w), np.float32)  # (P, H, W)
    return FrameConditioning(channels=channels, amr_mask=amr, local_masks=local.astype(np.float32), frame_index=t,
                             passes=passes, **camera_view(shot, t))


def frame_conditioning(shot: Shot, edits: Edits | None) -> Conditioning:
    """frame -> its conditioning under `edits` (`apply_edits`), or the plain channels when None."""
    if edits is None:
        return functools.partial(plain_conditioning, shot)
    return functools.partial(apply_edits, shot, edits)


def resolve_reference(shot: Shot, edits: Edits, base_dir: str | Path | None = None) -> tuple[int, np.ndarray] | None:
    """(frame index where the reference sits, linear RGB float32 (H, W, 3) at the shot's size, in the model's
    exposure), or None.

    An image file sits at `reference.at` (default 0): `reference_image`, at the shot's size and in its units. A shot
    frame reference is `rgb/` of that frame. Frames in the shot's units are scaled by its `irradiance_scale`, as the
    model's training frames are (`x2video.train.cache`), so a reference of a shot whose irradiance was normalised on
    load has the brightness the model saw.
    """
    ref = edits.reference
    if ref is None:
        return None
    scale = np.float32(shot.info.irradiance_scale)
    if ref.frame is None:
        if not 0 <= ref.position < shot.num_frames:
            raise ValueError(f"reference image {ref.path}: placed at frame {ref.position}, outside the shot's {shot.num_frames} frames")
        path = Path(ref.path)  # type: ignore[arg-type]
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        return ref.position, reference_image(path, scale, shot.size)
    if not shot.has("rgb"):
        raise ValueError(f"reference frame {ref.frame}: shot {shot.info.source!r} has no rgb channel")
    if not 0 <= ref.frame < shot.num_frames:
        raise ValueError(f"reference frame {ref.frame} outside the shot's {shot.num_frames} frames")
    return ref.frame, shot.channel("rgb", ref.frame).astype(np.float32) * scale


def reference_image(path: Path, scale: np.float32, size: tuple[int, int]) -> np.ndarray:
    """The user's reference image file as linear RGB float32 (H, W, 3) at `size` = (H, W) (`fit_image`): PNG/JPG
    sRGB-decoded (a display picture: taken as it is), EXR taken as linear in the shot's units and multiplied by
    `scale`, the shot's `irradiance_scale` (negatives and NaN zeroed)."""
    from x2video.channels import srgb_to_linear
    from x2video.io.convention import zero_nonfinite
    from x2video.io.image import read_image

    img = read_image(path)
    colour = [c for c in img.channel_names if c not in ("A", "a")]
    if len(colour) == 1:
        colour = colour * 3
    names = [c for c in ("R", "G", "B") if c in img.planes] if all(c in img.planes for c in "RGB") else colour[:3]
    rgb = img.stack(names)
    rgb = zero_nonfinite(rgb, str(path), "reference")
    rgb = srgb_to_linear(rgb) if img.max_int is not None else np.maximum(rgb, 0) * scale
    return fit_image(rgb, size)


def fit_image(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Centre-crop `rgb` to the aspect ratio of `size` = (H, W), then resize to it (area when shrinking)."""
    H, W = size
    h, w = rgb.shape[:2]
    if h * W > w * H:  # too tall
        ch = max(1, round(w * H / W))
        y0 = (h - ch) // 2
        rgb = rgb[y0 : y0 + ch]
    elif h * W < w * H:  # too wide
        cw = max(1, round(h * W / H))
        x0 = (w - cw) // 2
        rgb = rgb[:, x0 : x0 + cw]
    if rgb.shape[:2] == (H, W):
        return np.ascontiguousarray(rgb, dtype=np.float32)
    interp = cv2.INTER_AREA if rgb.shape[0] > H else cv2.INTER_LINEAR
    return cv2.resize(np.ascontiguousarray(rgb, dtype=np.float32), (W, H), interpolation=interp)
