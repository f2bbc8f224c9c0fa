"""`FrameConditioning`: what the model eats for one frame, after `Edits` were applied to a `Shot` (`x2video.conditioning.edited`)."""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np

from x2video.channels import INTRINSIC, LIGHT_PASSES, PASSES

if TYPE_CHECKING:
    from x2video.shot import Shot


@dataclass
class FrameConditioning:
    """The edited intrinsic channels of one frame plus its masks.

    channels: name -> float32 (H, W, C) in the channel convention (docs/ARCHITECTURE.md), or None when the channel is
        dropped (missing from the shot, or dropped by an edit). Regions masked out by a
        "Mask A|M|R" edit are already zero in albedo/roughness/metallic.
    amr_mask: float32 (H, W) in {0, 1}: union of the regions where A|M|R was masked out
        (the UNet's last input channel).
    local_masks: float32 (P, H, W) in [0, 1], one per local prompt, in `prompts.local` order.
    """

    channels: dict[str, np.ndarray | None]
    amr_mask: np.ndarray
    local_masks: np.ndarray
    frame_index: int = 0
    #: reads the frame's depth (H, W, 1) along the camera's -z when the shot has it (geometry: no edit changes it;
    #: read only when asked, `depth()`), and the camera's vertical field of view in degrees when known: tier 1's
    #: screen-space hints (`x2video.model.screen_space`) use them
    depth_source: Callable[[], np.ndarray] | None = field(default=None, repr=False, compare=False)
    fov_y_deg: float | None = None
    #: tier 1's frame of these channels (H, W, 3), linear: what a model whose `ModelConfig.prior` is "tier1" samples its
    #: residual over. Derived from the channels and the model's tier-1 net; `x2video.tiers.encoder.Encoder` fills it
    #: before encoding (None until then, and for every other model)
    prior: np.ndarray | None = field(default=None, repr=False, compare=False)
    #: the frame's passes where the shot has them (`x2video.channels.PASSES`: diffuse_color, glossy, emission; a
    #: Blender shot's), float32 (H, W, 3), the light ones in the model's exposure (times the shot's irradiance_scale,
    #: as irradiance) and edited with it by the light operations; what the formula over the base rebuilds
    #: (`x2video.base.passes`). No network reads them.
    passes: dict[str, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    def depth(self) -> np.ndarray | None:
        return None if self.depth_source is None else self.depth_source()

    def __post_init__(self) -> None:
        for name in INTRINSIC:
            self.channels.setdefault(name, None)

    @property
    def size(self) -> tuple[int, int]:
        return self.amr_mask.shape[:2]

    def cropped(self, rows: slice, cols: slice) -> FrameConditioning:
        """The conditioning of pixels [rows, cols] (views of the channels, masks and passes; no depth reader, which
        reads the whole frame): for work that is per pixel (the formula over the base, `x2video.base.stage`)."""
        amr, local = self.amr_mask, self.local_masks
        return FrameConditioning(channels={k: None if v is None else v[rows, cols] for k, v in self.channels.items()},
                                 amr_mask=amr[rows, cols] if np.ndim(amr) == 2 else amr,
                                 local_masks=local[:, rows, cols] if np.ndim(local) == 3 else local,
                                 frame_index=self.frame_index, fov_y_deg=self.fov_y_deg,
                                 passes={k: v[rows, cols] for k, v in self.passes.items()})


#: frame index -> that frame's (edited) conditioning
Conditioning = Callable[[int], FrameConditioning]


def camera_view(shot: Shot, t: int) -> dict:
    """FrameConditioning's geometry of frame `t` of `shot`: its depth reader (None without a depth channel) and
    vertical field of view (None without cameras)."""
    poses = shot.info.poses
    pose = poses[t] if poses is not None and t < len(poses) else None
    return {"depth_source": functools.partial(shot.channel, "depth", t) if shot.has("depth") else None,
            "fov_y_deg": None if pose is None else pose.fov_y_deg}


def shot_passes(shot: Shot, t: int) -> dict[str, np.ndarray]:
    """Frame `t`'s passes of `shot` (`FrameConditioning.passes`): those frame `t` carries (a keyframe shot's
    diffuse_color and glossy on its keyframes only), the light ones times its irradiance_scale (the model's exposure)."""
    scale = np.float32(shot.info.irradiance_scale)
    out = {}
    for name in PASSES:
        if shot.has(name, t):
            v = np.asarray(shot.channel(name, t), np.float32)
            out[name] = v * scale if name in LIGHT_PASSES and scale != 1 else v
    return out


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
        passes=shot_passes(shot, t),
    )
