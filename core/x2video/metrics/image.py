"""Per-frame fidelity metrics, PSNR and SSIM, on display-referred images (paper, Experiments: metrics).

Every metric in `x2video.metrics` compares *display-referred* images: float32 (H, W, 3) in
[0, 1], i.e. linear HDR radiance passed through the project's one display transform
`x2video.channels.tonemap` (clip to [0, 1], then sRGB encoding). `to_display` does that
conversion for frames given in linear light (what the `Renderer` and `rgb/` EXRs hold).
"""
from __future__ import annotations

import math

import numpy as np

from x2video.channels import tonemap

#: The two colour spaces frames may arrive in: "linear" HDR radiance or "display" sRGB in [0, 1].
SPACES = ("linear", "display")
#: Display-referred input may overshoot [0, 1] by this much (float rounding) before it is an error.
_DISPLAY_TOL = 1e-3

#: SSIM constants and window of Wang et al. 2004 ("Image quality assessment: from error
#: visibility to structural similarity", IEEE TIP 13(4)): K1, K2, Gaussian sigma, window side.
SSIM_K1 = 0.01
SSIM_K2 = 0.03
SSIM_SIGMA = 1.5
SSIM_WINDOW = 11


def to_display(frame: np.ndarray, space: str = "linear", *, what: str = "frame") -> np.ndarray:
    """(H, W, 3) frame in `space` -> float32 (H, W, 3) display-referred image in [0, 1].

    "linear": linear HDR radiance, tone-mapped with `x2video.channels.tonemap`.
    "display": already display-referred; checked to lie in [0, 1] (within 1e-3) and clipped.
    `what` names the frame in error messages (e.g. "prediction frame 12").
    """
    if space not in SPACES:
        raise ValueError(f"{what}: unknown colour space {space!r} (expected one of {SPACES})")
    x = np.asarray(frame)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"{what}: expected an (H, W, 3) RGB image, got shape {x.shape}")
    x = x.astype(np.float32, copy=False)
    if not np.isfinite(x).all():
        raise ValueError(f"{what}: contains NaN or infinite values")
    if space == "linear":
        return tonemap(x)
    lo, hi = float(x.min()), float(x.max())
    if lo < -_DISPLAY_TOL or hi > 1.0 + _DISPLAY_TOL:
        raise ValueError(f"{what}: display-referred values must lie in [0, 1], got [{lo:.4g}, {hi:.4g}]")
    return np.clip(x, 0.0, 1.0)


def _check_pair(pred: np.ndarray, gt: np.ndarray, what: str) -> None:
    if pred.shape != gt.shape:
        raise ValueError(f"{what}: prediction shape {pred.shape} differs from ground-truth shape {gt.shape}")


def psnr(pred: np.ndarray, gt: np.ndarray, *, what: str = "frame") -> float:
    """Peak signal-to-noise ratio in dB, 10 log10(1 / MSE), of two display-referred images in [0, 1].

    The standard definition with peak value 1 (data range of a display-referred image) and the
    MSE taken over all pixels and all three channels. Identical images give `math.inf`.
    """
    _check_pair(pred, gt, what)
    mse = float(np.mean((pred.astype(np.float64) - gt.astype(np.float64)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def ssim(pred: np.ndarray, gt: np.ndarray, *, what: str = "frame") -> float:
    """Mean SSIM of Wang et al. 2004 between two display-referred (H, W, 3) images in [0, 1].

    The paper's configuration: an 11x11 circular-symmetric Gaussian window with sigma 1.5,
    K1 = 0.01, K2 = 0.03, dynamic range L = 1, population (not sample) covariances; the SSIM
    map is averaged over the pixels whose window lies inside the image, and over the three
    colour channels (SSIM is defined on one channel; averaging RGB channels is the usual
    colour extension). Implemented by scikit-image's `structural_similarity`, whose
    ``gaussian_weights=True, sigma=1.5, use_sample_covariance=False`` options its docs give
    as "to match the implementation of Wang et al.".
    """
    from skimage.metrics import structural_similarity

    _check_pair(pred, gt, what)
    h, w = gt.shape[:2]
    if min(h, w) < SSIM_WINDOW:
        raise ValueError(f"{what}: SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {w}x{h}")
    return float(
        structural_similarity(
            pred.astype(np.float64),
            gt.astype(np.float64),
            data_range=1.0,
            channel_axis=-1,
            gaussian_weights=True,
            sigma=SSIM_SIGMA,
            use_sample_covariance=False,
            K1=SSIM_K1,
            K2=SSIM_K2,
        )
    )
