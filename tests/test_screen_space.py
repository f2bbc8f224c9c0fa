"""Tier 1's screen-space hints (x2video.model.screen_space): reflections marched through depth, the split-sum
specular colour, and nets that read them through the renderer, whole-frame and in tiles."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from x2video.model import residual as R
from x2video.model import screen_space as SS
from x2video.render.events import FramesReady
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.shot import ArrayShot, CameraPose

pytestmark = pytest.mark.usefixtures("torch_one_thread")

H, W, FOV = 48, 64, 60.0
WALL_Z, FLOOR_Y = 5.0, -1.0


def floor_and_wall() -> dict[str, np.ndarray]:
    """A camera at the origin looking down -z over a mirror-flat floor (y = -1) towards a bright wall (z = -5):
    planar depth, camera-space normals, formula 0.1 on the floor and 2 on the wall."""
    d = SS.view_dirs(H, W, FOV)
    t_floor = np.where(d[..., 1] < 0, FLOOR_Y / np.minimum(d[..., 1], -1e-9), np.inf)
    t_wall = WALL_Z / -d[..., 2]
    floor = t_floor < t_wall
    depth = np.where(floor, t_floor, t_wall) * -d[..., 2]
    normal = np.where(floor[..., None], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]).astype(np.float32)
    formula = np.where(floor[..., None], 0.1, 2.0).astype(np.float32) * np.ones(3, np.float32)
    return {"depth": depth.astype(np.float32), "normal": normal, "formula": formula, "floor": floor}


def test_a_mirror_floor_reflects_the_wall_and_the_wall_reflects_nothing_on_screen():
    s = floor_and_wall()
    geo = np.ones((H, W), bool)
    col, hit, out = SS.reflections(s["formula"], s["depth"], s["normal"], geo, np.zeros((H, W), bool), FOV)
    floor, wall = s["floor"], ~s["floor"]
    # floor pixels a few rows below the wall's base see the wall in the mirror: the marched ray lands on it (the
    # rows right at the base reflect the base itself, within the two pixels a ray must travel)
    near_base = floor & np.roll(wall, 8, axis=0) & ~np.roll(wall, 2, axis=0)
    assert near_base.sum() > 20
    assert hit[near_base].mean() > 0.9
    assert np.allclose(col[near_base & (hit > 0)], np.log1p(2.0), atol=1e-5)
    # the wall faces the camera: above the horizon its mirrored rays rise back past the camera, off screen; below
    # it they come down onto the floor in front of it, and what they show is the floor's formula
    upper = wall & (np.arange(H)[:, None] < H // 2)
    assert hit[upper].max() == 0 and out[upper].max() == 0
    low = wall & (hit > 0)
    assert low.any() and np.allclose(col[low], np.log1p(0.1), atol=1e-5)
    # no floor pixel sees its own floor in a flat mirror: whatever a floor ray meets is the wall
    assert np.allclose(col[floor & (hit > 0)], np.log1p(2.0), atol=1e-5)


def test_rays_that_meet_unlit_pixels_mark_the_outside():
    s = floor_and_wall()
    window = ~s["floor"] & (np.arange(W)[None, :] < W // 2)  # the wall's left half is a window
    geo = np.ones((H, W), bool)
    col, hit, out = SS.reflections(s["formula"], s["depth"], s["normal"], geo, window, FOV)
    base = s["floor"] & np.roll(~s["floor"], 8, axis=0) & ~np.roll(~s["floor"], 2, axis=0)
    left, right = base & (np.arange(W)[None, :] < W // 2 - 4), base & (np.arange(W)[None, :] > W // 2 + 4)
    assert out[left].mean() > 0.9 and hit[left].max() == 0 and col[left].max() == 0
    assert hit[right].mean() > 0.9 and out[right].max() == 0


def test_specular_colour_is_the_metals_albedo_head_on_and_dim_for_rough_dielectrics():
    albedo = np.full((2, 2, 3), [0.9, 0.6, 0.2], np.float32)
    one, zero = np.ones((2, 2), np.float32), np.zeros((2, 2), np.float32)
    metal = SS.specular_colour(albedo, one, zero, one)
    assert np.allclose(metal, albedo, atol=0.02)
    dielectric = SS.specular_colour(albedo, zero, one, one)
    assert np.all(dielectric < 0.06) and np.all(dielectric > 0)
    grazing = SS.specular_colour(albedo, zero, zero, np.full((2, 2), 0.02, np.float32))
    assert np.all(grazing > dielectric)  # Fresnel: a smooth dielectric brightens towards grazing angles


def channels(rng: np.random.Generator, s: dict) -> dict[str, np.ndarray]:
    return {"albedo": rng.uniform(0.1, 0.9, (H, W, 3)).astype(np.float32), "normal": s["normal"],
            "roughness": rng.uniform(0, 1, (H, W, 1)).astype(np.float32), "metallic": (rng.uniform(0, 1, (H, W, 1)) > 0.7).astype(np.float32),
            "irradiance": rng.uniform(0.2, 2, (H, W, 3)).astype(np.float32)}


def test_features_without_hints_are_unchanged_and_hints_without_depth_are_flagged():
    rng = np.random.default_rng(0)
    s = floor_and_wall()
    ch = channels(rng, s)
    base, form = R.features(ch)
    assert base.shape == (R.BASE_PLANES, H, W)
    x, form2 = R.features(ch, hints=True, depth=s["depth"], fov_y_deg=FOV)
    assert x.shape == (R.BASE_PLANES + SS.N_PLANES, H, W)
    assert np.array_equal(x[:R.BASE_PLANES], base) and np.array_equal(form, form2)
    flag = R.BASE_PLANES + SS.PLANES.index("depth_present")
    assert x[flag].min() == 1
    nd, _ = R.features(ch, hints=True, depth=None, fov_y_deg=FOV)
    assert nd[flag].max() == 0 and nd[R.BASE_PLANES + SS.SSR_LOG.start:R.BASE_PLANES + SS.PLANES.index("ssr_outside") + 1].max() == 0
    assert np.array_equal(nd[R.BASE_PLANES + 2:R.BASE_PLANES + 9], x[R.BASE_PLANES + 2:R.BASE_PLANES + 9])  # view and specular colour stay
    with pytest.raises(ValueError, match="in_channels"):
        R.ResidualConfig(in_channels=25, hints=True)


def hint_net() -> R.ResidualNet:
    torch.manual_seed(0)
    net = R.ResidualNet(R.ResidualConfig(widths=(8, 16, 16), hints=True)).eval()
    torch.nn.init.normal_(net.out.weight, std=0.3)
    assert net.cfg.in_channels == R.BASE_PLANES + SS.N_PLANES
    return net


def test_a_hint_net_renders_a_shot_with_depth_and_tiles_agree(tmp_path):
    rng = np.random.default_rng(1)
    s = floor_and_wall()
    ch = channels(rng, s)
    net = hint_net()
    # tiles: the hint planes are made on the whole frame, so tiling gives the whole-frame pass
    x, f = R.features(ch, hints=True, depth=s["depth"], fov_y_deg=FOV)
    with torch.inference_mode():
        want = R.apply(net, torch.from_numpy(x)[None], torch.from_numpy(f)[None])[0].permute(1, 2, 0).numpy()
    got = R.apply_tiled(net, ch, tile=16, halo=32, feather=8, depth=s["depth"], fov_y_deg=FOV)
    assert float(np.abs(np.log1p(got) - np.log1p(want)).max()) < 1e-4
    # through the renderer: the shot's depth and camera reach the net; a shot without depth still renders
    frames = {k: np.stack([v, v]) for k, v in ch.items()}
    pose = CameraPose(cam_to_world=np.eye(4), fov_y_deg=FOV)
    with_depth = ArrayShot({**frames, "depth": np.stack([s["depth"]] * 2)[..., None]}, poses=[pose, pose])
    without = ArrayShot(frames)

    from sampling_fake import FakeModel

    model = FakeModel()
    model.residual_net = net

    def render(shot) -> dict[int, np.ndarray]:
        frames: dict[int, np.ndarray] = {}
        Renderer(model).render(shot, None, RenderSettings(quality="residual", guess_unseen=True),
                               lambda e: frames.update(e.frames) if isinstance(e, FramesReady) else None)
        return frames

    out_d, out_n = render(with_depth), render(without)
    assert np.allclose(out_d[0], want, atol=1e-4)
    assert out_n[0].shape == (H, W, 3) and np.isfinite(out_n[0]).all()
    assert not np.allclose(out_d[0], out_n[0], atol=1e-3)  # the reflections changed the frame


def test_fov_out_of_range_is_an_error():
    with pytest.raises(ValueError, match="field of view"):
        SS.focal(10, 190.0)
    assert math.isclose(SS.focal(10, None), SS.focal(10, SS.DEFAULT_FOV_Y_DEG))
