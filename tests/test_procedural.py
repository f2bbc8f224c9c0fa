"""Procedural interiors (issue 3): determinism, channel validity, shading identities, camera paths, motion, captions."""
from __future__ import annotations

import numpy as np
import pytest

from x2video.channels import tonemap
from x2video.procedural.camera import camera_path
from x2video.procedural.colors import NAMED_SRGB, linear_rgb, names_in, nearest_index, nearest_names
from x2video.procedural.motion import _rays, motion_field
from x2video.procedural.renderer import ProceduralRenderer
from x2video.procedural.scene import generate_scene

W, H = 64, 48


@pytest.fixture(scope="module")
def renderer():
    r = ProceduralRenderer(W, H)
    yield r
    r.release()


def _frames(renderer, seed, n=3, size=(W, H)):
    sc = generate_scene(seed)
    poses = camera_path(sc, n, size[0] / size[1], seed)
    renderer.set_scene(sc)
    return sc, poses, [renderer.render(p) for p in poses]


def test_same_seed_gives_identical_frames(renderer):
    sc1, p1, f1 = _frames(renderer, 11)
    other = ProceduralRenderer(W, H)
    try:
        sc2, p2, f2 = _frames(other, 11)
    finally:
        other.release()
    assert sc1.caption == sc2.caption and sc1.object_captions() == sc2.object_captions()
    for a, b in zip(p1, p2):
        np.testing.assert_array_equal(a.cam_to_world, b.cam_to_world)
    for a, b in zip(f1, f2):
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    _, _, f3 = _frames(renderer, 12)
    assert not np.array_equal(f1[0]["rgb"], f3[0]["rgb"])  # and another seed is another room


@pytest.mark.parametrize("seed", [0, 3, 6])
def test_channels_are_valid(renderer, seed):
    sc, _, frames = _frames(renderer, seed, n=2)
    ids_known = {0} | {o.id for o in sc.objects}
    for f in frames:
        assert f["rgb"].shape == (H, W, 3) and f["roughness"].shape == (H, W, 1) and f["ids"].dtype == np.int32
        for k, v in f.items():
            assert np.isfinite(v).all(), k
        assert np.abs(np.linalg.norm(f["normal"], axis=-1) - 1).max() < 1e-3
        assert f["albedo"].min() >= 0 and f["albedo"].max() <= 1
        for k in ("roughness", "metallic"):
            assert f[k].min() >= 0 and f[k].max() <= 1
        assert f["irradiance"].min() >= 0 and f["rgb"].min() >= 0
        assert f["depth"].min() > 0.04 and f["depth"].max() < 15
        assert set(np.unique(f["ids"])) <= ids_known
        # camera-space normals (OpenGL: +Z towards the viewer) face the camera: dot(n, pixel -> eye) > 0
        rx, ry = _rays(H, W, 60.0)
        d = f["depth"][..., 0]
        to_eye = -np.stack([rx * d, ry * d, -d], -1)
        assert ((f["normal"] * to_eye).sum(-1) > -1e-3).mean() > 0.99
        # well exposed: little clipping of the tone-mapped image
        assert (f["rgb"].max(-1) > 1.0).mean() < 0.2


def _diffuse_scene(seed, floor_roughness=None, floor_metallic=0.0):
    """A room whose every material is purely Lambertian (roughness 1, metallic 0, no emission), optionally with a
    dark grey floor of the given roughness/metallic."""
    sc = generate_scene(seed)
    for m in sc.materials:
        if not m.sky:
            m.roughness, m.metallic, m.emission = 1.0, 0.0, np.zeros(3, np.float32)
    floor = sc.materials[sc.objects[0].parts[0].material]
    floor.albedo, floor.pattern = linear_rgb("dark grey"), "flat"
    if floor_roughness is not None:
        floor.roughness, floor.metallic = floor_roughness, floor_metallic
    return sc


def _looking_down(sc):
    from x2video.procedural.camera import look_matrix
    from x2video.shot import CameraPose

    return CameraPose(look_matrix(np.array([sc.width / 2, 1.7, sc.depth / 2]), 0.3, np.radians(-50)), 60.0)


def test_diffuse_material_rgb_is_albedo_times_irradiance(renderer):
    sc = _diffuse_scene(4)
    renderer.set_scene(sc)
    for pose in (camera_path(sc, 1, W / H, 4)[0], _looking_down(sc)):
        f = renderer.render(pose)
        solid = f["ids"][..., 0] > 0  # sky (id 0) shows only emitted light
        a = tonemap(f["rgb"])[solid]
        b = tonemap(f["albedo"] * f["irradiance"])[solid]
        assert np.abs(a - b).max() < 0.01


def test_specular_and_reflections_add_on_glossy_surfaces(renderer):
    """Threshold: on a glossy floor (roughness 0.1) the shaded image exceeds albedo x irradiance by >= 0.02 of the
    display range on average, and a mirror-like metal floor (diffuse = 0) still shows >= 0.05 of reflected light."""
    pose = None
    out = {}
    for name, rough, metal in (("matte", None, 0.0), ("glossy", 0.1, 0.0), ("metal", 0.1, 1.0)):
        sc = _diffuse_scene(5, rough, metal)
        renderer.set_scene(sc)
        pose = pose or _looking_down(sc)
        out[name] = renderer.render(pose)
    floor = out["matte"]["ids"][..., 0] == 1
    assert floor.mean() > 0.2
    g = out["glossy"]
    extra = tonemap(g["rgb"])[floor] - tonemap(g["albedo"] * g["irradiance"])[floor]
    assert extra.mean() >= 0.02
    m = out["metal"]
    assert np.allclose(m["metallic"][floor], 1.0)
    assert tonemap(m["rgb"])[floor].mean() >= 0.05
    mt = out["matte"]
    assert np.abs(tonemap(mt["rgb"])[floor] - tonemap(mt["albedo"] * mt["irradiance"])[floor]).max() < 0.01


@pytest.mark.parametrize("seed", list(range(0, 40, 3)))
def test_camera_path_stays_clear_of_geometry_and_is_smooth(seed):
    sc = generate_scene(seed)
    poses = camera_path(sc, 60, W / H, seed)
    pos = np.array([p.cam_to_world[:3, 3] for p in poses])
    assert np.allclose(pos[:, 1], 1.7)
    for p in pos:
        assert 0.2 < p[0] < sc.width - 0.2 and 0.2 < p[2] < sc.depth - 0.2
        for o in sc.objects:
            for part in o.parts:
                inside = np.all(p > part.lo - 0.05) and np.all(p < part.hi + 0.05)
                assert not inside, f"seed {seed}: camera at {p} inside {o.caption}"
    steps = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    assert steps.max() < 0.0501 and (steps.min() > 0.045 or steps.max() < 1e-9)  # ~constant speed (no cusps), or a pan
    fwd = np.array([-p.cam_to_world[:3, 2] for p in poses])
    turn = np.degrees(np.arccos(np.clip((fwd[1:] * fwd[:-1]).sum(1), -1, 1)))
    assert turn.max() < 3.0


def test_motion_reprojects_next_frame_onto_this_one():
    w, h = 96, 72
    r = ProceduralRenderer(w, h)
    try:
        sc = generate_scene(8)
        poses = camera_path(sc, 11, w / h, 8)
        r.set_scene(sc)
        f0, f1 = r.render(poses[0]), r.render(poses[10])  # ten frames apart: several pixels of motion
    finally:
        r.release()
    import cv2

    flow = motion_field(f0["depth"], poses[0], f1["depth"], poses[10])
    valid = np.isfinite(flow).all(-1)
    assert valid.mean() > 0.7
    assert np.nanmean(np.linalg.norm(flow, axis=-1)) > 1.0

    def err(fl):
        gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        fl = np.nan_to_num(fl)
        warped = cv2.remap(f1["albedo"], gx + fl[..., 0], gy + fl[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        ok = valid.copy()
        ok[[0, -1], :] = ok[:, [0, -1]] = False
        return np.abs(warped - f0["albedo"])[ok].mean()

    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    fl = np.nan_to_num(flow)
    ids_back = cv2.remap(f1["ids"][..., 0].astype(np.float32), gx + fl[..., 0], gy + fl[..., 1], cv2.INTER_NEAREST)
    assert (ids_back == f0["ids"][..., 0])[valid].mean() > 0.95  # the same object lands there
    e = err(flow)
    assert e < 0.04  # what is left is texture aliasing at 96x72
    assert err(np.zeros_like(flow)) > 1.5 * e  # no motion is much worse
    for shift in ([0.5, 0], [-0.5, 0], [0, 0.5], [0, -0.5]):  # and the flow is right to under half a pixel
        assert err(flow + np.array(shift, np.float32)) > e


@pytest.mark.parametrize("seed", [1, 2, 9, 13])
def test_captions_name_the_rendered_colour_and_category(seed):
    """Each visible object's caption names its category, and the colours it names are what its albedo shows: together
    they are among the 2 nearest colour names of >= 60% of its pixels, and the median albedo is one of them."""
    w, h = 96, 72
    r = ProceduralRenderer(w, h)
    try:
        sc = generate_scene(seed)
        poses = camera_path(sc, 30, w / h, seed)
        r.set_scene(sc)
        frames = [r.render(poses[t]) for t in (0, 15, 29)]
    finally:
        r.release()
    names = list(NAMED_SRGB)
    checked = 0
    for o in sc.objects:
        assert o.category in o.caption
        colours = names_in(o.caption)
        assert colours, f"no colour word in {o.caption!r}"
        px = np.concatenate([f["albedo"][f["ids"][..., 0] == o.id] for f in frames])
        if len(px) < 30:
            continue
        idx = {names.index(c) for c in colours}
        near = nearest_index(px, k=2)  # (P, 2)
        explained = np.isin(near, list(idx)).any(1).mean()
        assert explained >= 0.6, f"seed {seed}: {o.caption!r}: only {explained:.0%} of its pixels look {colours}"
        assert set(nearest_names(np.median(px, axis=0), k=2)) & set(colours), f"seed {seed}: {o.caption!r}"
        checked += 1
    assert checked >= 4
