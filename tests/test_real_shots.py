"""Real shots (issue 29): units in = units out, any frame size, other tools' layouts, `info` exit codes."""
import json

import numpy as np
import pytest

from x2video.channels import tonemap
from x2video.cli import main as cli
from x2video.io import load_shot
from x2video.io.image import read_image, write_exr

LAYER = "ViewLayer"


def _unit(rng, shape):
    n = rng.normal(size=shape)
    n[..., 2] = np.abs(n[..., 2]) + 0.5
    return (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)


def write_blender_shot(folder, frames=2, h=37, w=53, seed=0):
    """Multi-layer EXR frames with Blender's pass names (Cycles: DiffCol, DiffDir, DiffInd, a basecolor AOV,
    world-space Normal, Combined), plus cameras.json; returns the exact diffuse radiance basecolor x (DiffDir + DiffInd)."""
    rng = np.random.default_rng(seed)
    want = []
    for t in range(frames):
        base = rng.uniform(0.05, 0.95, (h, w, 3)).astype(np.float32)
        direct = rng.uniform(0, 40, (h, w, 3)).astype(np.float32)  # Cycles' absolute units: far from 0.18 grey
        indirect = rng.uniform(0, 8, (h, w, 3)).astype(np.float32)
        normal = _unit(rng, (h, w, 3))
        diffuse = base * (direct + indirect)
        planes = {}
        for comp, i in zip("RGB", range(3)):
            planes[f"{LAYER}.DiffCol.{comp}"] = base[..., i] * 0.9
            planes[f"{LAYER}.DiffDir.{comp}"] = direct[..., i]
            planes[f"{LAYER}.DiffInd.{comp}"] = indirect[..., i]
            planes[f"{LAYER}.basecolor.{comp}"] = base[..., i]
            planes[f"{LAYER}.Combined.{comp}"] = diffuse[..., i] * 1.1
        for comp, i in zip("XYZ", range(3)):
            planes[f"{LAYER}.Normal.{comp}"] = normal[..., i]
        write_exr(folder / f"frame_{t + 1:04d}.exr", planes, "float")
        want.append(diffuse)
    cams = {"convention": "opengl_cam_to_world", "frames": [{"frame": t, "cam_to_world": np.eye(4).tolist(), "fov_y_deg": 50.0} for t in range(frames)]}
    (folder / "cameras.json").write_text(json.dumps(cams))
    return want


def test_blender_exr_formula_render_round_trips_units(tmp_path, caplog):
    shot_dir = tmp_path / "blender"
    shot_dir.mkdir()
    want = write_blender_shot(shot_dir)
    shot = load_shot(shot_dir)
    scale = shot.info.irradiance_scale
    assert scale < 0.1, "the loader normalised this bright shot's exposure (the test needs a scale far from 1)"

    out = tmp_path / "out"
    with caplog.at_level("INFO"):
        assert cli(["render", str(shot_dir), "--quality", "formula", "--out", str(out)]) == 0
    assert "MP4 exposure" in caplog.text and f"{scale:.4g}" in caplog.text
    for t, diffuse in enumerate(want):
        img = read_image(out / f"{t:06d}.exr")
        rgb = img.stack(["R", "G", "B"])
        # absolute units: exactly basecolor x (DiffDir + DiffInd), up to half-float rounding
        np.testing.assert_allclose(rgb, diffuse, rtol=2e-3, atol=1e-3)
        assert img.attributes["x2video:irradiance_scale"] == pytest.approx(scale, rel=1e-6)


@pytest.mark.parametrize("exposure", ["auto", "0", "-3"])
def test_mp4_exposure_is_the_users_setting(tmp_path, exposure):
    import av

    shot_dir = tmp_path / "blender"
    shot_dir.mkdir()
    want = write_blender_shot(shot_dir, frames=1, h=16, w=24)
    scale = load_shot(shot_dir).info.irradiance_scale
    out = tmp_path / "a.mp4"
    assert cli(["render", str(shot_dir), "--quality", "formula", "--exposure", exposure, "--out", str(out)]) == 0
    with av.open(str(out)) as c:
        got = next(c.decode(video=0)).to_ndarray(format="rgb24").astype(np.float32)
    gain = scale if exposure == "auto" else 2.0 ** float(exposure)
    mean = lambda a: a.reshape(-1, 3).mean(0)  # noqa: E731 - per-pixel noise does not survive yuv420p, its mean does
    assert np.abs(mean(got) - mean(tonemap(want[0] * gain) * 255)).max() < 4
    if exposure != "auto":  # a different exposure really changes the picture
        assert np.abs(mean(got) - mean(tonemap(want[0] * scale) * 255)).max() > 10


def test_exposure_must_be_auto_or_stops(tmp_path, capsys):
    with pytest.raises(SystemExit):
        cli(["render", "--demo", "--exposure", "bright", "--out", str(tmp_path / "a.mp4")])
    assert "--exposure" in capsys.readouterr().err


def _shot_folder(root, frames, h, w, seed=0):
    from x2video.io.shotdir import ShotWriter
    from x2video.shot import ArrayShot

    rng = np.random.default_rng(seed)
    n = np.zeros((frames, h, w, 3), np.float32)
    n[..., 2] = 1
    shot = ArrayShot({
        "albedo": rng.uniform(0, 1, (frames, h, w, 3)).astype(np.float32),
        "normal": n,
        "roughness": np.full((frames, h, w, 1), 0.5, np.float32),
        "irradiance": rng.uniform(0, 2, (frames, h, w, 3)).astype(np.float32),
    })
    with ShotWriter(root, shot.info) as wr:
        for t in range(frames):
            wr.write_frame(t, shot.frame(t))
    return root


def test_53x37_renders_with_the_tiny_model(tmp_path):
    """Not a multiple of the VAE factor 8: padded for the model (real UNet and VAE, untrained) and cropped back."""
    import torch

    torch.set_num_threads(1)
    shot = _shot_folder(tmp_path / "odd", 3, 37, 53)
    out = tmp_path / "frames"
    assert cli(["render", str(shot), "--untrained", "--device", "cpu", "--steps", "1", "--window", "3", "--out", str(out)]) == 0
    for t in range(3):
        img = read_image(out / f"{t:06d}.exr")
        assert (img.height, img.width) == (37, 53)
        assert np.isfinite(img.stack(["R", "G", "B"])).all()


def test_1366x768_formula_and_model_sizes(tmp_path):
    """1366 is not a multiple of 8: the formula path needs no padding, the Renderer pads to 1368 and crops back."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from sampling_fake import FakeModel, make_shot
    from x2video.sampling.events import FramesReady, RenderSettings
    from x2video.sampling.renderer import Renderer

    shot = _shot_folder(tmp_path / "hd", 1, 768, 1366)
    out = tmp_path / "hd_out"
    assert cli(["render", str(shot), "--quality", "formula", "--out", str(out)]) == 0
    img = read_image(out / "000000.exr")
    assert (img.height, img.width) == (768, 1366)
    from x2video.model.shading import classical_shading

    want = classical_shading(load_shot(shot).frame(0))
    np.testing.assert_allclose(img.stack(["R", "G", "B"])[::7, ::9], want[::7, ::9], rtol=2e-3, atol=2e-3)

    events: list = []
    model = FakeModel()
    Renderer(model).render(make_shot(2, height=768, width=1366), None, RenderSettings(steps=1, window=2), on_event=events.append)
    frames = {f: a for e in events if isinstance(e, FramesReady) for f, a in e.frames.items()}
    assert sorted(frames) == [0, 1] and all(a.shape == (768, 1366, 3) for a in frames.values())
    assert model.windows[0].cond.shape[-2:] == (96, 171)  # 768 x 1368 in the model


def test_info_exits_1_on_a_corrupt_png(tmp_path, capsys):
    from x2video.io.image import write_ldr

    rng = np.random.default_rng(0)
    for t in range(3):
        write_ldr(tmp_path / "shot" / "albedo" / f"{t:04d}.png", rng.uniform(0, 1, (8, 10, 3)))
    assert cli(["info", str(tmp_path / "shot"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["problems"] == []
    bad = tmp_path / "shot" / "albedo" / "0002.png"
    bad.write_bytes(bad.read_bytes()[:40])  # truncated
    assert cli(["info", str(tmp_path / "shot"), "--json"]) == 1
    rep = json.loads(capsys.readouterr().out)
    assert len(rep["problems"]) == 1 and "0002.png" in rep["problems"][0]
    assert cli(["info", str(tmp_path / "shot")]) == 1
    assert "problems (1)" in capsys.readouterr().out
