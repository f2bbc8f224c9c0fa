"""Where a regional render keeps the diffusion sampler's pixels, and the feathered seam around them (docs/ARCHITECTURE.md "Tiers")."""
from __future__ import annotations

import numpy as np

from x2video.conditioning.frame import FrameConditioning

#: pixels of the outward feather `feathered` draws (tier 1's unseen-light rule keeps the formula over it)
FEATHER_PX = 6.0
#: pixels inside a generated region over which tier 2's frame gives way to tier 1's at its edge (`composite_weight`).
#: Chosen on the 20 v3 validation rooms, 3 objects' A|M|R masked out, truth apart (`bench.pathtraced --seam-px`,
#: bench/results/pathtraced/seam_val_*.json), whole frame / inside the masks / TC under auto: a hard edge (0) 17.21 /
#: 14.23 / 2.43, 1.5 px 17.18 / 14.18 / 2.47, 3 px (the earlier width, chosen on the outside scenes) 17.02 / 13.96 /
#: 2.54, 6 px 16.69 / 13.49 / 2.55; the band around the masks is tier 1's in all (19.75; the earlier 6-px outward
#: feather 16.46). 1.5 px rather than the hard edge: 0.03 dB from it on masks that follow an object's silhouette, and
#: a painted mask need not follow one.
SEAM_PX = 1.5


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


def composite_weight(mask: np.ndarray, px: float | None = None) -> np.ndarray:
    """(H, W) weights in [0, 1] of tier 2's frame where a regional render meets tier 1: 1 deeper than `px` pixels inside
    the generated region, falling linearly to 1/px on its edge pixels, 0 outside. The seam lies inside the region, so
    the surfaces around it keep tier 1's frame untouched: with an outward feather the sampler's frame, poor right
    around a masked object, reached them (outside scenes, 3 objects masked: the 6-pixel band around the masks at 17.7 dB
    against tier 1's 22.9; inward, 22.9, and 0.04 dB more inside the masks; docs/evaluations/2026-12-04-diffusion-over-tier1.md)."""
    import cv2

    px = SEAM_PX if px is None else px  # read at call time: bench.pathtraced --seam-px varies it to choose it
    if px < 0:  # the earlier rule, for comparison: the sampler's frame feathered -px pixels outward
        return feathered(mask, -px)
    m = (np.asarray(mask, np.float32) > 0.5).astype(np.uint8)
    if px == 0 or not m.any():
        return m.astype(np.float32)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)  # exact Euclidean distance to the nearest pixel outside the region; 1 on its edge
    return np.clip(inside / px, 0, 1).astype(np.float32)
