"""`FrameConditioning`: what the model eats for one frame, after `Edits` were applied to a `Shot`."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from x2video.channels import INTRINSIC


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

    def __post_init__(self) -> None:
        for name in INTRINSIC:
            self.channels.setdefault(name, None)

    @property
    def size(self) -> tuple[int, int]:
        return self.amr_mask.shape[:2]


@dataclass
class Prompts:
    """Global prompt (everywhere) and local prompts (each only inside its mask)."""

    global_prompt: str = ""
    local: list[str] = field(default_factory=list)
