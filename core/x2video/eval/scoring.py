"""Scores a set of rendered shots against the ground truth with `x2video.metrics.MetricSuite`; FID with cached ground-truth features.

Every row of every table compares against the same ground-truth frames, so their Inception
features are extracted once per data set (`Scorer`) instead of once per row; FID is then
`x2video.metrics.fid_from_features` of the row's frames against them. LPIPS and FVD are
reported once per results file as unavailable (`x2video.metrics.unavailable_metrics`).
"""
from __future__ import annotations

import math
import time
from typing import Any, Sequence

import numpy as np

from x2video.eval.data import EvalShot
from x2video.metrics import MetricSuite, SuiteConfig, fid_from_features, inception_features, to_display

#: fields of `MetricSuite.results()` a row keeps (per-shot detail is kept separately)
_KEEP = ("frames", "psnr", "psnr_exact_frames", "ssim", "tc", "warp_error_pred", "warp_error_gt", "tc_pairs", "seconds_per_frame")


def _display(frames: Sequence[np.ndarray]) -> np.ndarray:
    return np.stack([to_display(f, "linear") for f in frames])  # (T, H, W, 3) in [0, 1]


class Scorer:
    """Scores predictions for a fixed list of held-out shots."""

    def __init__(self, shots: list[EvalShot], *, fid: bool = True, tc: bool = True, fid_batch: int = 16) -> None:
        self.shots = shots
        self.fid, self.tc, self.fid_batch = fid, tc, fid_batch
        self._gt_features: np.ndarray | None = None
        self.seconds = 0.0

    def gt_features(self) -> np.ndarray:
        """(F, 2048) Inception features of all ground-truth frames, in shot order (computed once)."""
        if self._gt_features is None:
            self._gt_features = np.concatenate([inception_features(_display(s.gt), batch_size=self.fid_batch) for s in self.shots])
        return self._gt_features

    def score(self, preds: dict[str, list[np.ndarray]], seconds: dict[str, float] | None = None) -> dict[str, Any]:
        """Metrics of linear predictions {shot name: T frames} (every shot of this scorer) against the
        ground truth; `seconds` {shot name: wall seconds to produce them} gives seconds per frame."""
        t0 = time.perf_counter()
        missing = [s.name for s in self.shots if s.name not in preds]
        if missing:
            raise ValueError(f"no prediction for shot(s) {', '.join(missing)}")
        suite = MetricSuite(SuiteConfig(space="linear", fid=False, tc=self.tc))
        shots: dict[str, Any] = {}
        for s in self.shots:
            r = suite.add_shot(s.name, preds[s.name], s.gt, s.motion, render_seconds=None if seconds is None else seconds[s.name])
            shots[s.name] = {k: r[k] for k in ("psnr", "ssim", "tc", "flow", "seconds_per_frame", "psnr_frames")}
        res = suite.results()
        out: dict[str, Any] = {k: res.get(k) for k in _KEEP}
        out["fid"], out["fid_note"] = None, None
        if not self.fid:
            out["fid_note"] = "not computed (--no-fid)"
        else:
            gt = self.gt_features()
            pred = np.concatenate([inception_features(_display(preds[s.name]), batch_size=self.fid_batch) for s in self.shots])
            if len(gt) < 2:
                out["fid_note"] = "needs at least 2 frames"
            else:
                fid = fid_from_features(pred, gt)
                out["fid"] = float(fid) if math.isfinite(fid) else None
                if len(gt) <= 2048:
                    out["fid_note"] = f"{len(gt)} frames < 2049: rank-deficient covariance; compare FIDs only at equal frame counts"
        out["shots"] = shots
        self.seconds += time.perf_counter() - t0
        return out
