"""Temporal consistency (TC): flow-warping error of a video relative to its ground truth (docs/ARCHITECTURE.md "Measuring it").

Flow-warping error (Lai et al. 2018, "Learning Blind Video Temporal Consistency", E_warp,
with the absolute instead of the squared difference, as "Measuring it" asks): for each pair of
consecutive frames, warp frame t+1 back onto frame t with the ground-truth flow F_t (pixel x
of frame t moves to x + F_t(x) in frame t+1), and average |I_t(x) - I_{t+1}(x + F_t(x))| over
the colour channels and the non-occluded pixels x; the video's error is the mean over pairs.

TC = warping error of the generated video / warping error of the ground-truth video, both with
the *same* ground-truth flows and masks, so the ground truth scores exactly 1.0 and a video
that flickers more than the ground truth scores above 1.

Flows: the renderer's exact motion (`motion/` EXRs; NaN where occluded or out of view) when
available, else OpenCV's DIS optical flow on the ground truth, with occlusions masked by the
forward-backward consistency check of Sundaram et al. 2010 (as Lai et al. and Ruder et al.).
All images are display-referred [0, 1] (`x2video.metrics.image.to_display`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np


@dataclass
class PairFlow:
    """Ground-truth flow from frame t to frame t+1 and where it may be trusted."""

    flow: np.ndarray  # (H, W, 2) float32 displacement in pixels, x right, y down; 0 where invalid
    valid: np.ndarray  # (H, W) bool: not occluded and x + flow inside the image


@dataclass
class WarpErrors:
    """Per-pair flow-warping errors of one video."""

    errors: np.ndarray  # (T-1,) float64 mean absolute error per pair, NaN where no pixel is valid
    valid_fraction: np.ndarray  # (T-1,) fraction of pixels the mask keeps

    @property
    def mean(self) -> float:
        """Mean over pairs that have valid pixels (NaN when none has)."""
        ok = np.isfinite(self.errors)
        return float(self.errors[ok].mean()) if ok.any() else math.nan


@dataclass
class TCResult:
    """TC of one video against its ground truth."""

    tc: float | None  # pred_error / gt_error; None when the ground truth's warping error is 0
    pred_error: float
    gt_error: float
    pairs: int  # frame pairs that contributed
    flow_source: str  # "exact" (renderer motion) or "dis" (OpenCV DIS on the ground truth)
    valid_fraction: float  # mean fraction of pixels kept by the occlusion mask


def _inside(flow: np.ndarray) -> np.ndarray:
    """(H, W) bool: the flow's target lies inside the image (bilinear taps available)."""
    h, w = flow.shape[:2]
    xs = np.arange(w, dtype=np.float32)[None, :] + flow[..., 0]
    ys = np.arange(h, dtype=np.float32)[:, None] + flow[..., 1]
    return (xs >= 0) & (xs <= w - 1) & (ys >= 0) & (ys <= h - 1)


def warp_back(frame: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Frame t+1 (H, W, C) warped onto frame t: out(x) = frame(x + flow(x)), bilinear (`cv2.remap`)."""
    h, w = flow.shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    map_x = gx + flow[..., 0]  # (H, W)
    map_y = gy + flow[..., 1]  # (H, W)
    out = cv2.remap(np.ascontiguousarray(frame, np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(frame.shape)


def flows_from_motion(motion: Sequence[np.ndarray] | np.ndarray, num_frames: int, size: tuple[int, int]) -> list[PairFlow]:
    """The renderer's exact motion (T-1 or T fields of (H, W, 2), NaN = occluded/out of view) -> flows.

    A field whose two components are not both finite, or whose target leaves the image, is masked.
    """
    n = len(motion)
    if n not in (num_frames - 1, num_frames):
        raise ValueError(f"motion: expected {num_frames - 1} fields for {num_frames} frames, got {n}")
    out = []
    for t in range(num_frames - 1):
        m = np.asarray(motion[t], dtype=np.float32)
        if m.shape != (size[0], size[1], 2):
            raise ValueError(f"motion frame {t}: expected shape {(size[0], size[1], 2)}, got {m.shape}")
        finite = np.isfinite(m).all(axis=-1)  # (H, W)
        flow = np.where(finite[..., None], m, 0.0).astype(np.float32)
        out.append(PairFlow(flow, finite & _inside(flow)))
    return out


def _gray_u8(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) display-referred [0, 1] -> (H, W) uint8 luma for DIS."""
    u8 = np.clip(np.rint(frame * 255.0), 0, 255).astype(np.uint8)
    return cv2.cvtColor(u8, cv2.COLOR_RGB2GRAY)


def forward_backward_mask(fwd: np.ndarray, bwd: np.ndarray) -> np.ndarray:
    """Sundaram et al. 2010 occlusion test: keep x where |w + w^|^2 < 0.01 (|w|^2 + |w^|^2) + 0.5,
    w = fwd(x), w^ = bwd(x + w) (the backward flow sampled where x lands)."""
    bwd_at = warp_back(bwd, fwd)  # (H, W, 2)
    lhs = np.sum((fwd + bwd_at) ** 2, axis=-1)
    rhs = 0.01 * (np.sum(fwd**2, axis=-1) + np.sum(bwd_at**2, axis=-1)) + 0.5
    return lhs < rhs


def dis_flows(gt_display: Sequence[np.ndarray], preset: int = cv2.DISOPTICAL_FLOW_PRESET_MEDIUM) -> list[PairFlow]:
    """OpenCV DIS optical flow (Kroeger et al. 2016) between consecutive ground-truth frames,
    forward and backward, with the forward-backward occlusion mask."""
    dis = cv2.DISOpticalFlow_create(preset)
    grays = [_gray_u8(f) for f in gt_display]
    out = []
    for t in range(len(grays) - 1):
        fwd = dis.calc(grays[t], grays[t + 1], None)  # (H, W, 2)
        bwd = dis.calc(grays[t + 1], grays[t], None)  # (H, W, 2)
        out.append(PairFlow(fwd, forward_backward_mask(fwd, bwd) & _inside(fwd)))
    return out


def warping_errors(frames_display: Sequence[np.ndarray], flows: Sequence[PairFlow]) -> WarpErrors:
    """Per-pair mean |I_t - warp(I_{t+1})| over masked pixels and channels (display-referred frames)."""
    if len(flows) != len(frames_display) - 1:
        raise ValueError(f"warping error: {len(frames_display)} frames need {len(frames_display) - 1} flows, got {len(flows)}")
    errs = np.full(len(flows), math.nan)
    frac = np.zeros(len(flows))
    for t, pf in enumerate(flows):
        warped = warp_back(frames_display[t + 1], pf.flow)  # (H, W, 3)
        n = int(pf.valid.sum())
        frac[t] = n / pf.valid.size
        if n:
            diff = np.abs(frames_display[t].astype(np.float64) - warped)  # (H, W, 3)
            errs[t] = float(diff[pf.valid].mean())
    return WarpErrors(errs, frac)


def ground_truth_flows(gt_display: Sequence[np.ndarray], motion: Sequence[np.ndarray] | np.ndarray | None) -> tuple[list[PairFlow], str]:
    """Exact flows from `motion` when given, else DIS on the ground truth; with the source's name."""
    if motion is not None:
        h, w = gt_display[0].shape[:2]
        return flows_from_motion(motion, len(gt_display), (h, w)), "exact"
    return dis_flows(gt_display), "dis"


def tc_from_errors(pred: WarpErrors, gt: WarpErrors) -> tuple[float | None, float, float, int]:
    """TC and the two mean errors over the pairs where both are defined."""
    ok = np.isfinite(pred.errors) & np.isfinite(gt.errors)
    if not ok.any():
        raise ValueError("TC: no frame pair has a non-occluded pixel; cannot measure temporal consistency")
    pe, ge = float(pred.errors[ok].mean()), float(gt.errors[ok].mean())
    return (pe / ge if ge > 0 else None), pe, ge, int(ok.sum())


def temporal_consistency(
    pred_display: Sequence[np.ndarray],
    gt_display: Sequence[np.ndarray],
    motion: Sequence[np.ndarray] | np.ndarray | None = None,
) -> TCResult:
    """TC of a generated video against its ground truth (both display-referred (H, W, 3) in [0, 1]).

    `motion`: the renderer's exact per-frame motion (T-1 fields of (H, W, 2)); None -> DIS flow
    computed on the ground truth.
    """
    if len(pred_display) != len(gt_display):
        raise ValueError(f"TC: prediction has {len(pred_display)} frames, ground truth {len(gt_display)}")
    if len(gt_display) < 2:
        raise ValueError(f"TC needs at least 2 frames, got {len(gt_display)}")
    flows, source = ground_truth_flows(gt_display, motion)
    pe, ge = warping_errors(pred_display, flows), warping_errors(gt_display, flows)
    tc, p, g, pairs = tc_from_errors(pe, ge)
    return TCResult(tc, p, g, pairs, source, float(ge.valid_fraction.mean()))
