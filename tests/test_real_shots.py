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
        assert cli(["render", str(shot_dir), "--quality", "formula", "--base", "off", "--out", str(out)]) == 0
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
    from x2video.io import ShotWriter
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
    """1366 is not a multiple of 8: the formula path needs no padding; the Renderer pads to 1368 and crops back, or by
    default runs the network at a working resolution and brings the frames back to 1366 x 768."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from sampling_fake import FakeModel, make_shot

    from x2video.render.events import FramesReady
    from x2video.render.renderer import Renderer
    from x2video.render.settings import RenderSettings

    shot = _shot_folder(tmp_path / "hd", 1, 768, 1366)
    out = tmp_path / "hd_out"
    assert cli(["render", str(shot), "--quality", "formula", "--out", str(out)]) == 0
    img = read_image(out / "000000.exr")
    assert (img.height, img.width) == (768, 1366)
    fr = load_shot(shot).frame(0)
    want = fr["albedo"] * fr["irradiance"]  # tier 0: the plain product
    np.testing.assert_allclose(img.stack(["R", "G", "B"])[::7, ::9], want[::7, ::9], rtol=2e-3, atol=2e-3)

    for working_pixels, latent in ((0, (96, 171)), (RenderSettings.working_pixels, (25, 44))):
        events: list = []
        model = FakeModel()
        Renderer(model).render(make_shot(2, height=768, width=1366), None, RenderSettings(steps=1, window=2, working_pixels=working_pixels),
                               on_event=events.append)
        frames = {f: a for e in events if isinstance(e, FramesReady) for f, a in e.frames.items()}
        assert sorted(frames) == [0, 1] and all(a.shape == (768, 1366, 3) for a in frames.values())
        # working_pixels 0: 768 x 1368 in the model (padded); by default a working resolution of 200 x 352 (x2video.conditioning.network)
        assert model.windows[0].cond.shape[-2:] == latent


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


# -- other tools' layouts -------------------------------------------------------------------------

def write_video(path, frames_u8, fps=12, lossless=True):
    """(T, H, W, 3) uint8 RGB frames as a video with PyAV: lossless RGB H.264 (exact values), or yuv420p as most tools write."""
    import av

    with av.open(str(path), mode="w") as c:
        s = c.add_stream("libx264rgb" if lossless else "libx264", rate=fps)
        s.width, s.height = frames_u8.shape[2], frames_u8.shape[1]
        s.pix_fmt = "rgb24" if lossless else "yuv420p"
        s.options = {"crf": "0"} if lossless else {"crf": "12"}
        for f in frames_u8:
            for pkt in s.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)


def vrgbx_frames(T=4, h=16, w=24, seed=0):
    """uint8 frames of the four V-RGBX channels: Albedo (sRGB), Normal (0.5 n + 0.5), Material (R roughness,
    G metallic), Irradiance (sRGB)."""
    rng = np.random.default_rng(seed)
    n = _unit(rng, (T, h, w, 3))
    return {
        "Albedo": rng.integers(0, 256, (T, h, w, 3), dtype=np.uint8),
        "Normal": np.round((n * 0.5 + 0.5) * 255).astype(np.uint8),
        "Material": np.concatenate([rng.integers(0, 256, (T, h, w, 2), dtype=np.uint8), np.zeros((T, h, w, 1), np.uint8)], -1),
        "Irradiance": rng.integers(0, 256, (T, h, w, 3), dtype=np.uint8),
    }


def test_vrgbx_video_set_loads_with_packed_material(tmp_path):
    from x2video.channels import srgb_to_linear

    frames = vrgbx_frames()
    for name, f in frames.items():
        write_video(tmp_path / f"scene_{name}.mp4", f)
    shot = load_shot(tmp_path)
    assert shot.channels == ("albedo", "normal", "roughness", "metallic", "irradiance")
    assert (shot.num_frames, *shot.size) == (4, 16, 24) and shot.info.fps == 12.0
    for t in (2, 0, 3):  # out of order: the decoder goes back
        np.testing.assert_allclose(shot.channel("albedo", t), srgb_to_linear(frames["Albedo"][t] / 255), atol=1e-6)
        np.testing.assert_allclose(shot.channel("roughness", t)[..., 0], frames["Material"][t, ..., 0] / 255, atol=1e-6)
        np.testing.assert_allclose(shot.channel("metallic", t)[..., 0], frames["Material"][t, ..., 1] / 255, atol=1e-6)
        n = frames["Normal"][t] / 255 * 2 - 1
        np.testing.assert_allclose(shot.channel("normal", t), n / np.linalg.norm(n, axis=-1, keepdims=True), atol=1e-5)
    irr = [srgb_to_linear(frames["Irradiance"][t] / 255) for t in range(4)]
    from x2video.io.convention import LUM_WEIGHTS

    lum = np.concatenate([(f @ LUM_WEIGHTS).ravel() for f in irr])
    scale = 0.18 / np.exp(np.log(np.maximum(lum, 1e-6)).mean())
    assert shot.info.irradiance_scale == pytest.approx(scale, rel=1e-4)
    np.testing.assert_allclose(shot.channel("irradiance", 1), irr[1] * scale, rtol=1e-5, atol=1e-6)
    # one file picks its shot among several in the folder
    write_video(tmp_path / "other_Albedo.mov", frames["Albedo"][:2])
    with pytest.raises(ValueError, match="several shots"):
        load_shot(tmp_path)
    assert load_shot(tmp_path / "other_Albedo.mov").num_frames == 2
    assert load_shot(tmp_path / "scene_Normal.mp4").channels == shot.channels


def test_yuv420p_videos_decode_close_to_their_frames(tmp_path):
    """What tools usually write (H.264 yuv420p): flat colours come back within 8-bit rounding and chroma loss."""
    T, h, w = 3, 16, 24
    colour = np.array([200, 120, 40], np.uint8)
    write_video(tmp_path / "clip_Albedo.mp4", np.broadcast_to(colour, (T, h, w, 3)).copy(), lossless=False)
    shot = load_shot(tmp_path)
    from x2video.channels import srgb_to_linear

    np.testing.assert_allclose(shot.channel("albedo", 1).mean((0, 1)), srgb_to_linear(colour / 255), atol=0.02)


def test_mismatched_videos_name_the_file(tmp_path):
    frames = vrgbx_frames()
    write_video(tmp_path / "s_Albedo.mp4", frames["Albedo"])
    write_video(tmp_path / "s_Normal.mp4", frames["Normal"][:3])
    with pytest.raises(ValueError, match="s_Normal.mp4: 3 frames"):
        load_shot(tmp_path)


@pytest.mark.parametrize("layout", ["vrgbx", "pass_folders"])
def test_per_channel_frame_folders(tmp_path, layout):
    from x2video.channels import srgb_to_linear
    from x2video.io.image import write_ldr

    frames = vrgbx_frames(T=3)
    names = ({"Albedo": "Albedo", "Normal": "Normal", "Material": "Material", "Irradiance": "Irradiance"} if layout == "vrgbx"
             else {"Albedo": "basecolor", "Normal": "normal", "roughness": "roughness", "metallic": "metallic"})
    for t in range(3):
        for key, folder in names.items():
            if key in frames:
                data = frames[key][t]
            else:  # one grey image per material channel
                data = np.repeat(frames["Material"][t][..., :1] if key == "roughness" else frames["Material"][t][..., 1:2], 3, -1)
            write_ldr(tmp_path / folder / f"{t:04d}.png", data)
    shot = load_shot(tmp_path)
    assert {"albedo", "normal", "roughness", "metallic"} <= set(shot.channels)
    np.testing.assert_allclose(shot.channel("albedo", 2), srgb_to_linear(frames["Albedo"][2] / 255), atol=1e-6)
    np.testing.assert_allclose(shot.channel("roughness", 1)[..., 0], frames["Material"][1, ..., 0] / 255, atol=1e-6)
    np.testing.assert_allclose(shot.channel("metallic", 1)[..., 0], frames["Material"][1, ..., 1] / 255, atol=1e-6)


def _look_at(eye, target):
    """4x4 OpenGL camera-to-world looking from eye at target (+Y up)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = eye - target
    z /= np.linalg.norm(z)
    x = np.cross([0, 1, 0], z)
    x /= np.linalg.norm(x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, np.cross(z, x), z, eye
    return m


def test_transforms_json_nerfstudio_and_instant_ngp(tmp_path):
    import math

    from x2video.io.image import write_ldr

    T, h, w = 3, 16, 24
    for t in range(T):
        write_ldr(tmp_path / "albedo" / f"{t:06d}.png", np.full((h, w, 3), 0.5))
    mats = [_look_at([t, 1.7, 3], [0, 1, 0]) for t in range(T)]
    # nerfstudio: focal lengths in pixels, frames listed out of order, 3x4 matrices allowed
    doc = {"camera_model": "OPENCV", "fl_x": 20.0, "fl_y": 20.0, "cx": 12, "cy": 8, "w": w, "h": h,
           "frames": [{"file_path": f"images/frame_{t + 1:05d}.png", "transform_matrix": mats[t].tolist()} for t in (2, 0, 1)]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    poses = load_shot(tmp_path).info.poses
    assert len(poses) == T
    for t in range(T):
        np.testing.assert_allclose(poses[t].cam_to_world, mats[t])
        assert poses[t].fov_y_deg == pytest.approx(math.degrees(2 * math.atan(h / 2 / 20.0)))
    # instant-ngp / NeRF-synthetic: only the horizontal angle, the aspect ratio from the frames
    doc = {"camera_angle_x": math.radians(90), "frames": [{"file_path": f"./r_{t}", "transform_matrix": mats[t].tolist()} for t in range(T)]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    p = load_shot(tmp_path).info.poses[1]
    assert p.fov_y_deg == pytest.approx(math.degrees(2 * math.atan(math.tan(math.radians(45)) * h / w)))
    # our cameras.json wins when both are there; anything else names both forms
    (tmp_path / "cameras.json").write_text(json.dumps({"frames": [{"frame": t, "cam_to_world": np.eye(4).tolist()} for t in range(T)]}))
    assert np.array_equal(load_shot(tmp_path).info.poses[2].cam_to_world, np.eye(4))
    (tmp_path / "cameras.json").write_text(json.dumps({"poses": [np.eye(4).tolist()] * T}))
    with pytest.raises(ValueError, match="cameras.json: not a camera file.*opengl_cam_to_world.*transforms.json"):
        load_shot(tmp_path)


@pytest.mark.parametrize("fmt", ["folder", "multilayer"])
def test_convert_writes_irradiance_in_the_inputs_units(tmp_path, fmt):
    shot_dir = tmp_path / "blender"
    shot_dir.mkdir()
    write_blender_shot(shot_dir, frames=2, h=8, w=12)
    src = load_shot(shot_dir)
    out = tmp_path / fmt
    assert cli(["convert", str(shot_dir), str(out), "--format", fmt]) == 0
    img = read_image(out / "irradiance" / "000000.exr" if fmt == "folder" else out / "000000.exr")
    stored = img.stack(["R", "G", "B"] if fmt == "folder" else ["irradiance.R", "irradiance.G", "irradiance.B"])
    np.testing.assert_allclose(stored, src.channel("irradiance", 0) / src.info.irradiance_scale, rtol=2e-3)  # Cycles' units
    back = load_shot(out)
    assert back.info.irradiance_scale == pytest.approx(src.info.irradiance_scale, rel=1e-3)
    np.testing.assert_allclose(back.channel("irradiance", 1), src.channel("irradiance", 1), rtol=3e-3, atol=1e-4)


def test_diffusionrenderer_gbuffer_frames(tmp_path):
    """DiffusionRenderer's inverse renderer writes gbuffer_frames/<clip>/<chunk>.<index:04d>.<pass>.png in one folder."""
    from x2video.channels import srgb_to_linear
    from x2video.io.image import write_ldr

    frames = vrgbx_frames(T=3)
    clip = tmp_path / "gbuffer_frames" / "clip"
    for t in range(3):
        write_ldr(clip / f"0000.{t:04d}.basecolor.png", frames["Albedo"][t])
        write_ldr(clip / f"0000.{t:04d}.normal.png", frames["Normal"][t])
        write_ldr(clip / f"0000.{t:04d}.roughness.png", np.repeat(frames["Material"][t][..., :1], 3, -1))
        write_ldr(clip / f"0000.{t:04d}.metallic.png", np.repeat(frames["Material"][t][..., 1:2], 3, -1))
        write_ldr(clip / f"0000.{t:04d}.depth.png", np.zeros((16, 24, 3)))  # display-normalised: not read as metres
    shot = load_shot(clip)
    assert shot.channels == ("albedo", "normal", "roughness", "metallic") and shot.num_frames == 3
    np.testing.assert_allclose(shot.channel("albedo", 2), srgb_to_linear(frames["Albedo"][2] / 255), atol=1e-6)
    np.testing.assert_allclose(shot.channel("metallic", 1)[..., 0], frames["Material"][1, ..., 1] / 255, atol=1e-6)
    write_ldr(clip / "0001.0000.basecolor.png", frames["Albedo"][0])
    with pytest.raises(ValueError, match="2 chunks.*stitched"):
        load_shot(clip)


def test_video_random_access_seeks(tmp_path):
    """Scrubbing a longer video (keyframe every 8 frames) back and forth gives exactly the frames of a sequential decode."""
    import av

    from x2video.io.video import _Decoder

    rng = np.random.default_rng(3)
    frames = rng.integers(0, 256, (120, 8, 8, 3), dtype=np.uint8)
    path = tmp_path / "long_Albedo.mp4"
    with av.open(str(path), mode="w") as c:
        s = c.add_stream("libx264rgb", rate=24)
        s.width, s.height, s.pix_fmt = 8, 8, "rgb24"
        s.options = {"crf": "0", "g": "8", "keyint_min": "8"}
        for f in frames:
            for pkt in s.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)
    d = _Decoder(path)
    assert d.num_frames == 120
    opens, reopen = [], d._open
    d._open = lambda: (opens.append(1), reopen())[1]
    for t in (100, 3, 99, 60, 119, 0, 61, 118, 50):
        np.testing.assert_array_equal(d.read(t), frames[t])
    assert len(opens) <= 3, "going back seeks instead of decoding from the start each time"
