"""Loaders: folder per channel (EXR/PNG 8+16/JPG/TIFF), multi-layer EXR (ours and Blender's), XRGB sets."""
import json

import numpy as np
import pytest

from x2video.channels import srgb_to_linear
from x2video.io import detect_format, load_shot
from x2video.io.convention import LUM_WEIGHTS
from x2video.io.image import write_exr, write_ldr

H, W = 6, 8


def _unit(rng, shape):
    n = rng.normal(size=shape)
    return (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)


def _geo_scale(frames):
    lum = np.concatenate([(f @ LUM_WEIGHTS).ravel() for f in frames])
    return 0.18 / np.exp(np.log(np.maximum(lum, 1e-6)).mean())


def test_folder_mixed_formats(tmp_path):
    rng = np.random.default_rng(0)
    T = 3
    alb8 = rng.integers(0, 256, (T, H, W, 3)).astype(np.uint8)
    nrm = _unit(rng, (T, H, W, 3))
    rough = rng.random((T, H, W, 1))
    metal = rng.random((T, H, W, 3))
    irr = (rng.random((T, H, W, 3)) * 5).astype(np.float32)
    ids = rng.integers(0, 300, (T, H, W, 1)).astype(np.uint16)
    for t in range(T):
        write_ldr(tmp_path / "albedo" / f"frame_{t + 1:04d}.png", alb8[t])  # 1-based, 4 digits
        write_ldr(tmp_path / "normal" / f"n{t}.png", nrm[t] * 0.5 + 0.5, bits=16)
        write_ldr(tmp_path / "roughness" / f"r.{t:03d}.jpg", np.repeat(rough[t], 3, -1))
        write_ldr(tmp_path / "metallic" / f"{t}.tif", metal[t], bits=16)
        write_exr(tmp_path / "irradiance" / f"{t:06d}.exr", {c: irr[t][..., i] for i, c in enumerate("RGB")}, "float")
        write_ldr(tmp_path / "ids" / f"{t:06d}.png", ids[t])
    assert detect_format(tmp_path) == "folder"
    shot = load_shot(tmp_path)
    assert shot.info.channels == ("albedo", "normal", "roughness", "metallic", "irradiance", "ids")
    assert shot.num_frames == T and shot.size == (H, W)
    np.testing.assert_allclose(shot.channel("albedo", 2), srgb_to_linear(alb8[2] / 255), atol=1e-6)
    np.testing.assert_allclose(shot.channel("normal", 1), nrm[1], atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(shot.channel("normal", 1), axis=-1), 1, atol=1e-5)
    np.testing.assert_allclose(shot.channel("roughness", 0), rough[0], atol=0.03)  # JPG is lossy
    np.testing.assert_allclose(shot.channel("metallic", 0)[..., 0], metal[0][..., 0], atol=1e-4)  # TIFF 16: first of RGB
    assert (shot.channel("ids", 2)[..., 0] == ids[2][..., 0]).all()
    # no shot.json: irradiance exposure-normalised once for the whole shot (XRGB factor)
    s = _geo_scale(list(irr))
    assert shot.info.irradiance_scale == pytest.approx(s, rel=1e-5)
    np.testing.assert_allclose(shot.channel("irradiance", 1), irr[1] * s, rtol=1e-5)


def _blender_frame(rng, metal_region):
    world_n = _unit(rng, (H, W, 3))
    base = rng.uniform(0.1, 0.9, (H, W, 3)).astype(np.float32)
    diffcol = np.where(metal_region[..., None], 0, base)
    p = {}
    for i, c in enumerate("RGB"):
        p[f"ViewLayer.DiffCol.{c}"] = diffcol[..., i]
        p[f"ViewLayer.basecolor.{c}"] = base[..., i]
        p[f"ViewLayer.DiffDir.{c}"] = np.full((H, W), 0.5 + i * 0.1, np.float32)
        p[f"ViewLayer.DiffInd.{c}"] = np.full((H, W), 0.25, np.float32)
        p[f"ViewLayer.Combined.{c}"] = base[..., i]
    p["ViewLayer.Combined.A"] = np.ones((H, W), np.float32)
    for i, c in enumerate("XYZ"):
        p[f"ViewLayer.Normal.{c}"] = world_n[..., i]
    p["ViewLayer.roughness.X"] = np.full((H, W), 0.3, np.float32)
    p["ViewLayer.metallic.X"] = metal_region.astype(np.float32)
    p["ViewLayer.IndexOB.X"] = np.where(metal_region, 5.0, 2.0).astype(np.float32)
    p["ViewLayer.Depth.Z"] = np.full((H, W), 3.5, np.float32)
    return p, world_n, base


def _rot_y(deg):
    a = np.radians(deg)
    m = np.eye(4)
    m[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    m[:3, 3] = [1, 1.7, 2]
    return m


def test_blender_multilayer(tmp_path):
    rng = np.random.default_rng(1)
    metal = np.zeros((H, W), bool)
    metal[:3] = True
    frames = []
    for t in range(2):
        p, wn, base = _blender_frame(rng, metal)
        write_exr(tmp_path / f"render_{t:04d}.exr", p, "half")
        frames.append((wn, base))
    poses = [_rot_y(30 * t + 10) for t in range(2)]
    cameras = [{"frame": t, "cam_to_world": m.tolist()} for t, m in enumerate(poses)]
    (tmp_path / "cameras.json").write_text(json.dumps({"convention": "opengl_cam_to_world", "frames": cameras}))
    shot = load_shot(tmp_path)
    assert type(shot).__name__ == "MultilayerShot"
    # DiffCol is also read as it is: the diffuse colour the light passes were divided by (x2video.base.passes)
    assert shot.info.channels == ("albedo", "normal", "roughness", "metallic", "irradiance", "rgb", "ids", "depth", "diffuse_color")
    wn, base = frames[1]
    # basecolor AOV preferred over Diffuse Color (black on metals)
    np.testing.assert_allclose(shot.channel("albedo", 1), base, atol=2e-3)
    # world -> camera normals: n_cam = R^T n_world
    expect = wn @ poses[1][:3, :3]
    np.testing.assert_allclose(shot.channel("normal", 1), expect, atol=3e-3)
    # irradiance = DiffDir + DiffInd, exposure once per shot
    raw = np.float32([0.75, 0.85, 0.95])
    s = _geo_scale([np.broadcast_to(raw, (H, W, 3))])
    np.testing.assert_allclose(shot.channel("irradiance", 0)[0, 0], raw * s, rtol=2e-3)
    assert (shot.channel("ids", 0)[..., 0] == np.where(metal, 5, 2)).all()
    np.testing.assert_allclose(shot.channel("metallic", 0)[..., 0], metal)
    assert shot.channel("depth", 0)[0, 0, 0] == 3.5
    # without cameras.json: a warning, normals left in world space
    (tmp_path / "cameras.json").unlink()
    with pytest.warns(RuntimeWarning, match="world space"):
        shot = load_shot(tmp_path)
    np.testing.assert_allclose(shot.channel("normal", 1), wn, atol=3e-3)


def test_blender_diffcol_fallback_single_file(tmp_path):
    rng = np.random.default_rng(2)
    p, _, base = _blender_frame(rng, np.zeros((H, W), bool))
    p = {k: v for k, v in p.items() if ".basecolor." not in k and ".Normal." not in k}
    write_exr(tmp_path / "one.exr", p)
    shot = load_shot(tmp_path / "one.exr")
    assert shot.num_frames == 1 and "normal" not in shot.channels
    np.testing.assert_allclose(shot.channel("albedo", 0), base, atol=2e-3)
    assert shot.info.extra["passes"]["albedo"] == "ViewLayer.DiffCol"


def _release_exposure(img):
    """The XRGB release's load_exr_image(tonemaping=True), transcribed to numpy (Yxy round trip)."""
    M = np.array([[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]])
    Mi = np.array([[3.2404542, -1.5371385, -0.4985314], [-0.9692660, 1.8760108, 0.0415560], [0.0556434, -0.2040259, 1.0572252]])
    XYZ = img @ M.T
    s = np.maximum(XYZ.sum(-1), 1e-4)
    Y, x, y = XYZ[..., 1], XYZ[..., 0] / s, XYZ[..., 1] / s
    lum = img @ np.array([0.2125, 0.7154, 0.0721])
    Y = Y * 0.18 / max(np.exp(np.log(np.maximum(lum, 1e-6)).mean()), 1e-6)
    X = x / np.maximum(y, 1e-6) * Y
    Z = (1 - x - y) / np.maximum(y, 1e-4) * Y
    return np.clip(np.stack([X, Y, Z], -1) @ Mi.T, 0, 1)


def test_xrgb_single_set_and_sequence(tmp_path):
    rng = np.random.default_rng(3)
    a8 = rng.integers(0, 256, (H, W, 3)).astype(np.uint8)
    n = _unit(rng, (H, W, 3))
    n[n[..., 2] < 0] *= -1
    n8 = np.round((n * 0.5 + 0.5) * 255).astype(np.uint8)
    irr = (rng.random((H, W, 3)) * 2 + 0.05).astype(np.float32)
    one = tmp_path / "one"
    write_ldr(one / "kitchen-albedo.png", a8)
    write_ldr(one / "kitchen-normal.png", n8)
    write_ldr(one / "kitchen-roughness.png", np.full((H, W, 3), 128, np.uint8))
    write_ldr(one / "kitchen-metallic.png", np.zeros((H, W, 3), np.uint8))
    write_exr(one / "kitchen-irradiance.exr", {c: irr[..., i] for i, c in enumerate("RGB")}, "float")
    write_ldr(one / "kitchen-ref.png", a8)
    assert detect_format(one) == "xrgb" and detect_format(one / "kitchen-albedo.png") == "xrgb"
    shot = load_shot(one / "kitchen-normal.png")
    assert shot.info.channels == ("albedo", "normal", "roughness", "metallic", "irradiance", "rgb")
    np.testing.assert_allclose(shot.channel("albedo", 0), (a8 / 255.0) ** 2.2, rtol=1e-5, atol=1e-7)  # gamma 2.2, not sRGB
    nn = n8 / 255.0 * 2 - 1
    np.testing.assert_allclose(shot.channel("normal", 0), nn / np.linalg.norm(nn, axis=-1, keepdims=True), atol=1e-6)
    np.testing.assert_allclose(shot.channel("roughness", 0), 128 / 255, atol=1e-6)
    np.testing.assert_allclose(shot.channel("irradiance", 0), _release_exposure(irr.astype(np.float64)), atol=1e-4)
    np.testing.assert_allclose(shot.channel("rgb", 0), srgb_to_linear(a8 / 255), atol=1e-6)
    # a numbered sequence of sets: exposure once per shot, so frame brightness ratios survive
    seq = tmp_path / "seq"
    small = irr * 0.1
    for t in range(3):
        write_ldr(seq / f"k_{t + 7}-albedo.png", a8)
        write_exr(seq / f"k_{t + 7}-irradiance.exr", {c: small[..., i] * (t + 1) for i, c in enumerate("RGB")}, "float")
    s = load_shot(seq)
    assert s.num_frames == 3 and s.info.extra["xrgb_names"] == ["k_7", "k_8", "k_9"]
    scale = _geo_scale([small * (t + 1) for t in range(3)])
    assert s.info.irradiance_scale == pytest.approx(scale, rel=1e-5)
    f0, f2 = s.channel("irradiance", 0), s.channel("irradiance", 2)
    ok = f2 < 1
    np.testing.assert_allclose(f2[ok], 3 * f0[ok], rtol=1e-4)
