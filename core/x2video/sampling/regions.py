"""Where a regional render keeps the diffusion sampler's pixels, and the feathered seam around them (docs/ARCHITECTURE.md "Tiers")."""
from __future__ import annotations

import numpy as np

from x2video.conditioning import FrameConditioning

#: pixels of the feather between a generated region (tier 2) and its surroundings (tier 1)
FEATHER_PX = 6.0


def generated_region(cond: FrameConditioning) -> np.ndarray:
    """(H, W) bool: where a regional render keeps the sampler's pixels: the frame's A|M|R regions and its local
    prompts' masks (> 0.5)."""
    region = np.asarray(cond.amr_mask, np.float32) > 0.5
    if cond.local_masks.size:
        region = region | (np.asarray(cond.local_masks, np.float32) > 0.5).any(0)
    return region


def feathered(mask: np.ndarray, px: float = FEATHER_PX) -> np.ndarray:
    """(H, W) weights in [0, 1]: the mask grown by `px` pixels, then blurred within `px` (a Gaussian of
    sigma px/2 truncated at 2 sigma): 1 inside the mask, exactly 0 farther than 2 px from it."""
    import cv2

    m = (np.asarray(mask, np.float32) > 0.5).astype(np.float32)
    if px <= 0 or not m.any():
        return m
    k = int(2 * round(px) + 1)
    grown = cv2.dilate(m, np.ones((k, k), np.uint8))
    return np.clip(cv2.GaussianBlur(grown, (k, k), px / 2, borderType=cv2.BORDER_REPLICATE), 0, 1)
