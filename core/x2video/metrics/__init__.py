"""The paper's evaluation metrics: PSNR, SSIM, FID, TC, seconds per frame (LPIPS/FVD reported unavailable)."""
from x2video.metrics.fid import fid_from_features, fid_from_images, frechet_distance, inception_features
from x2video.metrics.image import psnr, ssim, to_display
from x2video.metrics.motion_io import read_motion
from x2video.metrics.suite import MetricSuite, SuiteConfig, evaluate_video
from x2video.metrics.temporal import TCResult, temporal_consistency
from x2video.metrics.timing import FrameTimer
from x2video.metrics.unavailable import UNAVAILABLE, unavailable_metrics

__all__ = [
    "FrameTimer",
    "MetricSuite",
    "SuiteConfig",
    "TCResult",
    "UNAVAILABLE",
    "evaluate_video",
    "fid_from_features",
    "fid_from_images",
    "frechet_distance",
    "inception_features",
    "psnr",
    "read_motion",
    "ssim",
    "temporal_consistency",
    "to_display",
    "unavailable_metrics",
]
