"""ShotWriter -> load_shot round trip of our shot folder (docs/SHOT_FORMAT.md)."""
import json

import numpy as np
import pytest

from x2video.io import ShotWriter, load_shot
from x2video.io.folder import FolderShot
from x2video.shot import CameraPose, ShotInfo

T, H, W = 3, 8, 12


def _frames(rng):
    out = []
    for t in range(T):
        n = rng.normal(size=(H, W, 3)).astype(np.float32)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        f = {
            "albedo": rng.random((H, W, 3), dtype=np.float32),
            "normal": n,
            "roughness": rng.random((H, W, 1), dtype=np.float32),
            "metallic": rng.random((H, W), dtype=np.float32),
            "irradiance": rng.random((H, W, 3), dtype=np.float32) * 4,
            "ids": rng.integers(0, 100_000, (H, W)),
            "depth": rng.random((H, W), dtype=np.float32) * 7,
            "rgb": rng.random((H, W, 3), dtype=np.float32) * 2,
        }
        if t < T - 1:
            f["motion"] = rng.normal(size=(H, W, 2)).astype(np.float32)
            f["motion"][0, 0] = np.nan
        out.append(f)
    return out


def test_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    poses = [CameraPose(np.eye(4) + t, 60.0) for t in range(T)]
    info = ShotInfo(num_frames=T, height=H, width=W, channels=(), fps=24.0, caption="a room", object_captions={3: "sofa"}, poses=poses, extra={"seed": 5})
    frames = _frames(rng)
    with ShotWriter(tmp_path / "s", info) as w:
        for t, f in enumerate(frames):
            w.write_frame(t, f)
    doc = json.loads((tmp_path / "s" / "shot.json").read_text())
    assert doc["format"] == "x2video-shot" and doc["irradiance_normalized"] is True
    shot = load_shot(tmp_path / "s")
    assert isinstance(shot, FolderShot)
    assert shot.info.channels == ("albedo", "normal", "roughness", "metallic", "irradiance", "rgb", "ids", "depth")
    assert (shot.num_frames, shot.size, shot.info.fps, shot.info.caption) == (T, (H, W), 24.0, "a room")
    assert shot.info.object_captions == {3: "sofa"} and shot.info.extra == {"seed": 5}
    assert shot.info.irradiance_scale == 1.0
    np.testing.assert_allclose(shot.info.poses[2].cam_to_world, np.eye(4) + 2)
    for t, f in enumerate(frames):
        got = shot.frame(t)
        for name in ("albedo", "normal", "irradiance", "rgb"):
            np.testing.assert_allclose(got[name], f[name], rtol=1e-3, atol=1e-3)
        np.testing.assert_allclose(got["metallic"][..., 0], f["metallic"], atol=1e-3)
        assert got["ids"].dtype == np.int32 and (got["ids"][..., 0] == f["ids"]).all()
        np.testing.assert_array_equal(got["depth"][..., 0], f["depth"])  # float32, exact
    m = shot.motion(0)
    assert np.isnan(m[0, 0]).all() and np.array_equal(m[1:], frames[0]["motion"][1:])
    assert shot.motion(T - 1) is None


def test_writer_checks(tmp_path):
    info = ShotInfo(num_frames=2, height=H, width=W, channels=())
    w = ShotWriter(tmp_path / "s", info)
    with pytest.raises(ValueError, match="'albedo' has shape"):
        w.write_frame(0, {"albedo": np.zeros((H, W, 1), np.float32)})
    with pytest.raises(IndexError):
        w.write_frame(2, {"albedo": np.zeros((H, W, 3), np.float32)})
    w.write_frame(0, {"albedo": np.zeros((H, W, 3), np.float32)})
    with pytest.raises(ValueError, match=r"'albedo' is missing frame\(s\) \[1\]"):
        w.close()
    assert not (tmp_path / "s" / "shot.json").exists()
    w.write_frame(1, {"albedo": np.zeros((H, W, 3), np.float32)})
    w.close()
    with pytest.raises(ValueError, match="already holds a shot"):
        ShotWriter(tmp_path / "s", info)
    ShotWriter(tmp_path / "s", info, overwrite=True)
    assert not list((tmp_path / "s" / "albedo").iterdir())
