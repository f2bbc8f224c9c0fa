"""PSNR, SSIM and the display transform of x2video.metrics against hand-checkable cases."""
import math

import cv2
import numpy as np
import pytest

from x2video.channels import tonemap
from x2video.metrics.image import SSIM_K1, SSIM_K2, psnr, ssim, to_display


def test_psnr_hand_value_and_identity():
    gt = np.zeros((8, 8, 3), np.float32)
    pred = np.full((8, 8, 3), 0.1, np.float32)  # MSE = 0.01 -> 20 dB
    assert psnr(pred, gt) == pytest.approx(20.0, abs=1e-5)  # 0.1 in float32
    pred[0, 0, 0] = 0.0  # lower MSE -> higher PSNR
    assert psnr(pred, gt) > 20.0
    assert psnr(gt, gt) == math.inf


def test_ssim_of_constant_images_is_the_luminance_term():
    # constant images: sigma terms vanish, SSIM = (2ab + C1) / (a^2 + b^2 + C1)
    a, b = 0.5, 0.25
    c1 = SSIM_K1**2
    want = (2 * a * b + c1) / (a * a + b * b + c1)
    got = ssim(np.full((16, 16, 3), a, np.float32), np.full((16, 16, 3), b, np.float32))
    assert got == pytest.approx(want, abs=1e-9)


def _reference_ssim(x: np.ndarray, y: np.ndarray) -> float:
    """Wang et al.'s ssim_index.m: 11x11 Gaussian (sigma 1.5) filter2 'valid', mean of the map; per channel."""
    r = np.arange(-5, 6, dtype=np.float64)
    g = np.exp(-(r**2) / (2 * 1.5**2))
    win = np.outer(g, g) / np.outer(g, g).sum()
    c1, c2 = SSIM_K1**2, SSIM_K2**2
    vals = []
    for c in range(x.shape[2]):
        a, b = x[..., c].astype(np.float64), y[..., c].astype(np.float64)

        def filt(im):
            return cv2.filter2D(im, cv2.CV_64F, win, borderType=cv2.BORDER_REFLECT)[5:-5, 5:-5]

        mu_a, mu_b = filt(a), filt(b)
        saa, sbb, sab = filt(a * a) - mu_a**2, filt(b * b) - mu_b**2, filt(a * b) - mu_a * mu_b
        m = ((2 * mu_a * mu_b + c1) * (2 * sab + c2)) / ((mu_a**2 + mu_b**2 + c1) * (saa + sbb + c2))
        vals.append(m.mean())
    return float(np.mean(vals))


def test_ssim_matches_wang_reference_formula():
    rng = np.random.default_rng(0)
    gt = cv2.GaussianBlur(rng.uniform(size=(40, 48, 3)).astype(np.float32), (5, 5), 1.0)
    pred = np.clip(gt * 0.8 + rng.normal(0, 0.05, gt.shape).astype(np.float32), 0, 1)
    got = ssim(pred, gt)
    assert got == pytest.approx(_reference_ssim(pred, gt), abs=1e-6)
    assert 0.0 < got < 0.99
    assert ssim(gt, gt) == pytest.approx(1.0, abs=1e-12)


def test_ssim_rejects_tiny_and_mismatched_images():
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(np.zeros((8, 20, 3)), np.zeros((8, 20, 3)))
    with pytest.raises(ValueError, match="shape"):
        psnr(np.zeros((8, 8, 3)), np.zeros((8, 9, 3)))


def test_to_display_tonemaps_linear_and_checks_display_input():
    lin = np.array([[[0.0, 0.18, 4.0]]], np.float32)
    np.testing.assert_array_equal(to_display(lin, "linear"), tonemap(lin))
    assert to_display(lin, "linear").max() == pytest.approx(1.0, abs=1e-6)
    with pytest.raises(ValueError, match=r"prediction frame 3: display-referred values"):
        to_display(lin, "display", what="prediction frame 3")
    bad = lin.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="frame 7: contains NaN"):
        to_display(bad, "linear", what="frame 7")
    with pytest.raises(ValueError, match="colour space"):
        to_display(lin, "srgb")
