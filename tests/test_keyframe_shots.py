"""Keyframe shots in Blender's multi-layer EXR (issue 51): Combined on some frames only, G-buffer passes between,
Emit + Env as the emission channel. Written here with Blender's pass names, no bpy needed (the add-on's own export
is tests/test_blender_addon.py)."""
import json

import numpy as np
import pytest

from x2video.cli import main as cli
from x2video.io import load_shot
from x2video.io.image import write_exr

H, W = 6, 8
GBUFFER = ("basecolor", "Normal", "Depth", "IndexOB", "Emit", "Env")


def write_keyframe_shot(folder, frames=5, keys=(0, 2, 4), shot_json=None):
    """Frames whose keyframes carry Combined + the diffuse light passes and the others G-buffer passes only, as the
    add-on writes them (File Output node names: no view-layer part). Returns (rgb, emission) per frame."""
    folder.mkdir()
    rgb, emission = [], []
    for t in range(frames):
        planes = {}
        emit = np.full((H, W, 3), 0.0, np.float32)
        emit[:2, :2] = (3.0, 2.0, 1.0)
        env = np.zeros((H, W, 3), np.float32)
        env[-1] = (0.5, 0.75, 1.0)  # a strip of sky
        base = np.full((H, W, 3), 0.5, np.float32)
        for i, c in enumerate("RGB"):
            planes[f"basecolor.{c}"], planes[f"Emit.{c}"], planes[f"Env.{c}"] = base[..., i], emit[..., i], env[..., i]
        for i, c in enumerate("XYZ"):
            planes[f"Normal.{c}"] = np.full((H, W), 1.0 if i == 2 else 0.0, np.float32)
        planes["Depth.V"] = np.full((H, W), 2.0 + t, np.float32)
        planes["IndexOB.V"] = np.ones((H, W), np.float32)
        light = np.full((H, W, 3), 40.0 + t, np.float32)  # Cycles' absolute units
        if t in keys:
            for i, c in enumerate("RGB"):
                planes[f"DiffDir.{c}"], planes[f"DiffInd.{c}"] = light[..., i], light[..., i] * 0.25
                planes[f"Combined.{c}"] = base[..., i] * light[..., i] * 1.25 + emit[..., i] + env[..., i]
        write_exr(folder / f"frame_{t:04d}.exr", planes, "float")
        rgb.append(base * light * 1.25 + emit + env if t in keys else None)
        emission.append(emit + env)
    cams = [{"frame": t, "cam_to_world": np.eye(4).tolist(), "fov_y_deg": 50.0} for t in range(frames)]
    (folder / "cameras.json").write_text(json.dumps({"convention": "opengl_cam_to_world", "frames": cams}))
    if shot_json is not None:
        (folder / "shot.json").write_text(json.dumps({"format": "x2video-shot", "version": 1, "num_frames": frames, **shot_json}))
    return rgb, emission


def test_keyframes_found_from_the_frames_that_carry_combined(tmp_path):
    rgb, emission = write_keyframe_shot(tmp_path / "shot")
    shot = load_shot(tmp_path / "shot")
    assert shot.keyframes == (0, 2, 4) and shot.info.rgb_frames == (0, 2, 4)
    assert [shot.has_rgb(t) for t in range(5)] == [True, False, True, False, True]
    assert {"albedo", "normal", "ids", "depth", "emission", "rgb"} <= set(shot.channels)
    assert "irradiance" not in shot.channels and shot.info.extra["keyframe_only"] == ["irradiance"]
    for t in range(5):
        fr = shot.frame(t)
        assert ("rgb" in fr) == (t in (0, 2, 4))
        np.testing.assert_allclose(fr["emission"], emission[t])  # Emit + Env, the file's units (as rgb)
        np.testing.assert_allclose(fr["depth"][..., 0], 2.0 + t)
        if t in (0, 2, 4):
            np.testing.assert_allclose(fr["rgb"], rgb[t], rtol=1e-6)  # rgb is not scaled on load; nor is emission
    with pytest.raises(KeyError, match="frame 3 has no rgb"):
        shot.channel("rgb", 3)


def test_light_passes_of_the_keyframes_are_read_on_the_keyframes(tmp_path):
    """DiffDir + DiffInd exist on the keyframes only: irradiance is offered there (`has(name, t)`, `channel_frames`),
    exposure-normalised once per shot from those frames, and reading it between them is a KeyError naming the frame."""
    write_keyframe_shot(tmp_path / "shot")
    shot = load_shot(tmp_path / "shot")
    assert shot.info.channel_frames == {"irradiance": (0, 2, 4)} and shot.frames_with("irradiance") == (0, 2, 4)
    assert [shot.has("irradiance", t) for t in range(5)] == [True, False, True, False, True]
    assert not shot.has("irradiance") and shot.has("albedo", 3) and not shot.has("rgb", 3) and shot.has("rgb", 4)
    scale = shot.info.irradiance_scale
    assert scale != pytest.approx(1.0)  # measured on the keyframes' light
    for t in (0, 2, 4):
        np.testing.assert_allclose(shot.channel("irradiance", t), (40.0 + t) * 1.25 * scale, rtol=1e-5)
        assert set(shot.frame(t, ("irradiance", "rgb", "albedo"))) == {"irradiance", "rgb", "albedo"}
    with pytest.raises(KeyError, match=r"frame 3 has no irradiance \(only frames 0, 2, 4 carry it\)"):
        shot.channel("irradiance", 3)
    assert set(shot.frame(3, ("irradiance", "rgb", "albedo"))) == {"albedo"}
    assert "irradiance" not in shot.frame(2)  # a frame's default channels are those every frame carries (and its rgb)


def test_emission_keeps_rgb_units_when_irradiance_is_normalised(tmp_path):
    """Every frame a keyframe: irradiance is normalised once per shot, rgb and emission stay in the file's units, so
    that rgb - emission is the reflected light."""
    rgb, emission = write_keyframe_shot(tmp_path / "shot", frames=3, keys=(0, 1, 2))
    shot = load_shot(tmp_path / "shot")
    assert shot.info.rgb_frames is None and shot.keyframes == (0, 1, 2) and "irradiance" in shot.channels
    assert shot.info.irradiance_scale != pytest.approx(1.0)
    np.testing.assert_allclose(shot.channel("emission", 1), emission[1])
    np.testing.assert_allclose(shot.channel("rgb", 1), rgb[1], rtol=1e-6)


def test_shot_json_keyframes_name_the_keyframes_and_are_checked(tmp_path):
    write_keyframe_shot(tmp_path / "a", keys=(0, 2, 4), shot_json={"keyframes": [0, 4]})
    assert load_shot(tmp_path / "a").keyframes == (0, 4)  # a frame with Combined need not be a keyframe
    write_keyframe_shot(tmp_path / "b", keys=(0, 2, 4), shot_json={"keyframes": [0, 3]})
    with pytest.raises(ValueError, match=r"frame_0003.exr: shot.json lists frame 3 as a keyframe, but it carries no Combined"):
        load_shot(tmp_path / "b")
    write_keyframe_shot(tmp_path / "c", keys=(0, 2, 4), shot_json={"keyframes": [0, 9]})
    with pytest.raises(ValueError, match=r"keyframes \[9\] lie outside the shot's 5 frames"):
        load_shot(tmp_path / "c")
    write_keyframe_shot(tmp_path / "d", keys=(0, 2, 4), shot_json={"keyframes": [4, 0]})
    with pytest.raises(ValueError, match="field 'keyframes' must list"):
        load_shot(tmp_path / "d")


def test_info_names_the_keyframes(tmp_path, capsys):
    write_keyframe_shot(tmp_path / "shot", shot_json={"keyframes": [0, 2, 4]})
    assert cli(["info", str(tmp_path / "shot")]) == 0
    out = capsys.readouterr().out
    assert "keyframes: 0, 2, 4 (3 of 5 frames carry rgb)" in out
    assert "irradiance is on the keyframes only: read there" in out
    assert cli(["info", str(tmp_path / "shot"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["keyframes"] == [0, 2, 4] and report["channel_frames"] == {"irradiance": [0, 2, 4]}
    assert report["ranges"]["irradiance"][0] > 0  # scanned on the keyframes
