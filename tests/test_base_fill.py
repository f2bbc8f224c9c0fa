"""The keyframe fill (x2video.base): keyframe shots load with gaps, `--keyframes` selects, reprojection is exact on
geometry it can see, flow carries shading where there is no depth, and pixels no keyframe saw are said and filled."""
from __future__ import annotations

import math

import numpy as np
import pytest

from x2video.base.camera import View, project, unproject
from x2video.base.fill import FillConfig, fill_frame, nearest_keyframes
from x2video.base.keyframes import only_keyframes, parse_keyframes
from x2video.io.load import load_shot
from x2video.io.shotdir import ShotWriter
from x2video.shot import ArrayShot, CameraPose

H, W, FOV = 48, 64, 50.0


def pose(x: float) -> CameraPose:
    m = np.eye(4)
    m[0, 3] = x
    return CameraPose(m, FOV)


def wall_shot(xs: list[float], depth: float = 5.0, hole_at: int | None = None) -> ArrayShot:
    """A textured wall facing the camera at `depth`, the camera sliding along x: rgb = albedo x shading, both smooth
    functions of the wall's world position; `hole_at`: on that frame a box in front of the wall (nearer) covers
    the middle, so its pixels are surfaces no keyframe saw."""
    f = (H / 2) / math.tan(math.radians(FOV) / 2)
    ys, xpix = np.mgrid[0:H, 0:W].astype(np.float64)
    frames = {k: [] for k in ("albedo", "normal", "depth", "rgb")}
    for i, x in enumerate(xs):
        d = np.full((H, W), depth)
        if hole_at == i:
            d[16:32, 24:40] = depth * 0.6
        wx = (xpix + 0.5 - W / 2) / f * d + x
        wy = -(ys + 0.5 - H / 2) / f * d
        albedo = np.stack([0.5 + 0.3 * np.sin(wx * 3), 0.4 + 0.2 * np.cos(wy * 2), np.full_like(wx, 0.3)], -1)
        shading = np.stack([1.0 + 0.5 * np.sin(wx * 0.7 + wy)] * 3, -1)
        frames["albedo"].append(albedo)
        frames["normal"].append(np.broadcast_to([0, 0, 1.0], (H, W, 3)))
        frames["depth"].append(d[..., None])
        frames["rgb"].append(albedo * shading)
    return ArrayShot({k: np.asarray(v, np.float32) for k, v in frames.items()}, poses=[pose(x) for x in xs])


def psnr(a: np.ndarray, b: np.ndarray, peak: float = 1.5) -> float:
    return float(10 * np.log10(peak**2 / np.mean((a - b) ** 2)))


def test_parse_keyframes():
    assert parse_keyframes("every:8", 20) == (0, 8, 16, 19)
    assert parse_keyframes("every:4", 9) == (0, 4, 8)
    assert parse_keyframes("8, 0,3", 9) == (0, 3, 8)
    for bad, msg in [("every:0", "at least 1"), ("every:x", "whole number"), ("0,12", "outside"), ("a,b", "comma-separated")]:
        with pytest.raises(ValueError, match=msg):
            parse_keyframes(bad, 10)


def test_nearest_keyframes():
    assert nearest_keyframes(5, (0, 8)) == (0, 8)
    assert nearest_keyframes(8, (0, 8)) == (8,)
    assert nearest_keyframes(10, (0, 8)) == (8,)
    with pytest.raises(ValueError, match="no keyframes"):
        nearest_keyframes(1, ())


def test_project_inverts_unproject():
    v = View.of(pose(0.3), (H, W))
    depth = np.random.default_rng(0).uniform(1, 9, (H, W))
    x, y, d = project(v, unproject(v, depth))
    ys, xs = np.mgrid[0:H, 0:W]
    np.testing.assert_allclose(x, xs, atol=1e-3)
    np.testing.assert_allclose(y, ys, atol=1e-3)
    np.testing.assert_allclose(d, depth, rtol=1e-5)


def test_reprojection_fills_frames_between_from_keyframes():
    shot = only_keyframes(wall_shot([0.0, 0.1, 0.2, 0.3, 0.4]), "every:4")
    assert shot.keyframes == (0, 4) and not shot.has_rgb(2)
    with pytest.raises(KeyError, match="frame 2 has no rgb"):
        shot.channel("rgb", 2)
    truth = wall_shot([0.0, 0.1, 0.2, 0.3, 0.4])
    for t in (1, 2, 3):
        res = fill_frame(shot, t)
        assert res.method == "depth" and res.holes == 0
        assert psnr(res.rgb, truth.channel("rgb", t)) > 40
    assert fill_frame(shot, 4).method == "keyframe"
    np.testing.assert_array_equal(fill_frame(shot, 4).rgb, truth.channel("rgb", 4))


def test_occluder_no_keyframe_saw_is_a_counted_hole():
    full = wall_shot([0.0, 0.1, 0.2], hole_at=1)
    shot = only_keyframes(full, "0,2")
    res = fill_frame(shot, 1)
    assert 0.05 < res.holes < 0.15  # the box: 16 x 16 of 48 x 64 pixels
    # around the box the wall is still carried exactly
    good = np.ones((H, W), bool)
    good[12:36, 20:44] = False
    assert psnr(res.rgb[good], full.channel("rgb", 1)[good]) > 40
    assert np.isfinite(res.rgb).all() and (res.rgb >= 0).all()


def test_a_rejection_threshold_matters():
    """With no depth check the occluder's pixels take the wall behind them from the keyframes (not a hole)."""
    shot = only_keyframes(wall_shot([0.0, 0.1, 0.2], hole_at=1), "0,2")
    loose = fill_frame(shot, 1, FillConfig(depth_tolerance=10.0))
    assert loose.holes == 0


def test_flow_fill_without_depth():
    full = wall_shot([0.0, 0.05, 0.1])
    arrays = {k: np.stack([full.channel(k, t) for t in range(3)]) for k in ("albedo", "normal", "rgb")}
    shot = only_keyframes(ArrayShot(arrays), "0,2")
    res = fill_frame(shot, 1)
    assert res.method == "flow"
    hold = full.channel("rgb", 0)
    assert psnr(res.rgb, full.channel("rgb", 1)) > psnr(hold, full.channel("rgb", 1)) + 3


def test_folder_shot_with_gaps_in_rgb(tmp_path):
    full = wall_shot([0.0, 0.1, 0.2, 0.3])
    with ShotWriter(tmp_path / "s", full.info) as w:
        for t in range(4):
            w.write_frame(t, full.frame(t))
    for t in (1, 2):
        (tmp_path / "s" / "rgb" / f"{t:06d}.exr").unlink()
    shot = load_shot(tmp_path / "s")
    assert shot.keyframes == (0, 3) and shot.has_rgb(3) and not shot.has_rgb(1)
    np.testing.assert_array_equal(shot.channel("rgb", 3), full.channel("rgb", 3).astype(np.float16).astype(np.float32))
    (tmp_path / "s" / "rgb" / "000009.exr").write_bytes((tmp_path / "s" / "rgb" / "000000.exr").read_bytes())
    with pytest.raises(ValueError, match="000009.exr: frame number 9 is outside"):
        load_shot(tmp_path / "s")
