"""Classical shading (shading prior / classical baseline), VAE range maps, irradiance mapping, latent scales, text encoder."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from x2video.model.config import VAEConfig
from x2video.model.shading import classical_shading, env_brdf_approx
from x2video.model.vae import build_vae, irradiance_to_unit, measure_latent_scales, to_vae_range, unit_to_irradiance


def _flat(albedo=(0.5, 0.4, 0.3), rough=1.0, metal=0.0, irr=(1.0, 1.0, 1.0), normal=(0, 0, 1), size=(4, 5)):
    h, w = size
    full = lambda v, c: np.broadcast_to(np.asarray(v, np.float32), (h, w, c)).copy()  # noqa: E731
    return {"albedo": full(albedo, 3), "normal": full(normal, 3), "roughness": full(rough, 1),
            "metallic": full(metal, 1), "irradiance": full(irr, 3)}


def test_env_brdf_matches_karis_reference_points():
    a, b = env_brdf_approx(np.array([[0.0]]), np.array([[1.0]]))
    assert abs(a[0, 0] - 0.9941) < 1e-3 and abs(b[0, 0] - 0.0059) < 1e-3  # smooth, head-on: F0 * 1 + 0
    a, b = env_brdf_approx(np.array([[0.0]]), np.array([[0.0]]))
    assert a[0, 0] + b[0, 0] > 0.9 and b[0, 0] > 0.5  # grazing, smooth: Fresnel towards 1
    r = np.linspace(0, 1, 11)[None]
    a, b = env_brdf_approx(r, np.full_like(r, 0.7))
    assert np.all(a >= 0) and np.all(b >= -1e-6) and np.all(a + b <= 1.0 + 1e-6)


def test_diffuse_dielectric_is_albedo_times_irradiance_plus_small_specular():
    ch = _flat(rough=1.0, metal=0.0, irr=(2.0, 1.0, 0.5))
    s = classical_shading(ch)
    diffuse = np.array([0.5 * 2.0, 0.4 * 1.0, 0.3 * 0.5])
    spec = s[0, 0] - diffuse
    assert s.shape == (4, 5, 3) and s.dtype == np.float32
    assert np.all(spec > 0) and np.all(spec < 0.05 * np.array([2.0, 1.0, 0.5]))  # F0 = 0.04 rough: a few %
    # a metal has no diffuse term and reflects with its albedo colour
    m = classical_shading(_flat(rough=0.1, metal=1.0, irr=(1, 1, 1)))[0, 0]
    assert np.allclose(m, np.array([0.5, 0.4, 0.3]), atol=0.03)


def test_missing_and_masked_inputs():
    ch = _flat()
    assert not classical_shading({**ch, "albedo": None}).any()
    assert not classical_shading({**ch, "irradiance": None}).any()
    no_spec = classical_shading({**ch, "normal": None})
    assert np.allclose(no_spec, np.asarray(ch["albedo"]) * ch["irradiance"])  # diffuse only
    mask = np.zeros((4, 5), np.float32)
    mask[:2] = 1
    masked = classical_shading(ch, mask)
    assert not masked[:2].any() and np.allclose(masked[2:], classical_shading(ch)[2:])
    with pytest.raises(ValueError, match="sizes differ"):
        classical_shading({**ch, "roughness": np.zeros((3, 5, 1), np.float32)})


def test_irradiance_mapping_is_monotonic_bounded_and_invertible():
    x = np.array([0.0, 0.01, 0.5, 1.0, 4.0, 100.0], np.float32)
    y = irradiance_to_unit(x)
    assert y[0] == -1 and np.all(np.diff(y) > 0) and np.all(y < 1)
    assert np.allclose(unit_to_irradiance(y)[:5], x[:5], rtol=1e-3, atol=1e-4)


def test_vae_range_maps():
    assert to_vae_range("roughness", np.full((2, 2, 1), 0.25, np.float32)).shape == (2, 2, 3)
    assert np.allclose(to_vae_range("metallic", np.ones((2, 2), np.float32)), 1)
    assert np.allclose(to_vae_range("albedo", np.zeros((2, 2, 3), np.float32)), -1)
    with pytest.raises(ValueError, match="irradiance"):
        to_vae_range("irradiance", np.zeros((2, 2, 3), np.float32))


def test_measure_latent_scales_is_one_over_std():
    torch.manual_seed(0)
    vae = build_vae(VAEConfig(block_out_channels=(8, 8), norm_num_groups=4)).eval()
    rng = np.random.default_rng(0)
    albedo = [rng.random((16, 16, 3), dtype=np.float32) for _ in range(3)]
    scales = measure_latent_scales(vae, {"albedo": albedo})
    with torch.no_grad():
        x = torch.from_numpy(np.stack([to_vae_range("albedo", a) for a in albedo])).permute(0, 3, 1, 2)
        std = vae.encode(x).latent_dist.mode().std().item()
    assert scales["albedo"] == pytest.approx(1 / std, rel=1e-5)
    assert scales["rgb"] == 1.0  # no samples: left at 1


def test_minilm_text_encoder_offline():
    from x2video.model.text import MiniLMTextEncoder

    enc = MiniLMTextEncoder(max_length=16)
    e = enc.encode(["a red velvet sofa", "", "a red velvet sofa"])
    assert e.shape == (3, 16, 384) and torch.equal(e[0], e[2])
    assert e[1, 2:].abs().max() == 0 and e[0, :6].abs().max() > 0  # padding zeroed, tokens not
    assert not torch.allclose(e[0], enc.encode(["a blue metal lamp"])[0])
    assert enc.encode([]).shape == (0, 16, 384)
