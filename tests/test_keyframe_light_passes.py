"""A keyframe shot's light passes (irradiance, diffuse_color, glossy) exist on its keyframes only: the loaders offer
them there (`Shot.has(name, t)`), and over the base an edit of a frame between takes its diffuse light from the fill's
shading (x2video.base.shading), so tier 0's difference there is (new albedo - old albedo) x the filled shading; the
tier choice does not generate merely because irradiance is on the keyframes only. The add-on's Cycles clip does the
same through Blender's passes (tests/test_addon_cycles_tiers.py)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from test_base_fill import wall_shot

from x2video.base.difference import SPILL_MARGIN, grow
from x2video.base.fill import fill_frame
from x2video.base.stage import BASE
from x2video.cli.info import inspect
from x2video.edits import Edits
from x2video.edits.masks import Mask
from x2video.edits.ops import AlbedoSet, Exposure
from x2video.io.load import load_shot
from x2video.io.shotdir import ShotWriter
from x2video.io.units import OutputUnits
from x2video.render.events import FramesReady, RenderStarted
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.shot import ArrayShot
from x2video.tiers import registry

XS = [0.0, 0.1, 0.2, 0.3]  # the camera slides along the wall; keyframes 0 and 3, frames 1 and 2 filled
KEYS, BETWEEN = (0, 3), (1, 2)
BOX = (slice(14, 30), slice(20, 44))  # the recoloured patch of the wall, in every frame
RED = (0.9, 0.05, 0.05)


def keyframe_folder(tmp_path, light_gaps: bool = True, rgb_gaps: bool = True):
    """`wall_shot` with its shading as irradiance, a glow as emission and a plain material, written as a shot folder (irradiance in
    Cycles' units, so the loader normalises it), then rgb/ and irradiance/ removed on the frames between."""
    wall = wall_shot(XS)
    arrays = {k: np.stack([wall.channel(k, t) for t in range(len(XS))]) for k in wall.channels}
    arrays["irradiance"] = 40.0 * arrays["rgb"] / arrays["albedo"]
    arrays["emission"] = np.zeros_like(arrays["rgb"])
    arrays["emission"][:, :4, :6] = 2.0
    arrays["rgb"] = arrays["albedo"] * arrays["irradiance"] + arrays["emission"]
    arrays["roughness"], arrays["metallic"] = np.full_like(arrays["depth"], 0.7), np.zeros_like(arrays["depth"])
    full = ArrayShot(arrays, poses=wall.info.poses)
    folder = tmp_path / "s"
    with ShotWriter(folder, full.info, irradiance_normalized=False) as w:
        for t in range(len(XS)):
            w.write_frame(t, full.frame(t))
    for t in BETWEEN:
        if rgb_gaps:
            (folder / "rgb" / f"{t:06d}.exr").unlink()
        if light_gaps:
            (folder / "irradiance" / f"{t:06d}.exr").unlink()
    return folder


def patch_edit(color=RED) -> Edits:
    e = Edits()
    m = np.zeros(wall_shot(XS[:1]).size, np.float32)
    m[BOX] = 1
    e.masks["patch"] = Mask(frames={0: m}, hold=True)
    e.ops.append(AlbedoSet(mask="patch", color=color))
    return e


def render(shot, settings: RenderSettings, edits=None) -> tuple[RenderStarted, dict[int, str], dict[int, np.ndarray]]:
    """(RenderStarted, frame -> its FramesReady mode, frame -> float64 rgb in the shot's input units)."""
    events: list = []
    Renderer(None).render(shot, edits, settings, events.append)
    units = OutputUnits.for_shot(shot)
    modes = {t: e.mode for e in events if isinstance(e, FramesReady) for t in e.frames}
    frames = {t: np.asarray(units.scene(f), np.float64) for e in events if isinstance(e, FramesReady) for t, f in e.frames.items()}
    return next(e for e in events if isinstance(e, RenderStarted)), modes, frames


def test_a_folder_shot_reads_irradiance_on_the_frames_that_carry_it(tmp_path):
    shot = load_shot(keyframe_folder(tmp_path))
    assert shot.keyframes == KEYS and shot.info.channel_frames == {"irradiance": KEYS}
    assert "irradiance" not in shot.channels and shot.info.extra["keyframe_only"] == ["irradiance"]
    assert [shot.has("irradiance", t) for t in range(4)] == [True, False, False, True]
    assert shot.info.irradiance_scale != pytest.approx(1.0)  # measured on the keyframes' light, once per shot
    with pytest.raises(KeyError, match=r"frame 2 has no irradiance \(only frames 0, 3 carry it\)"):
        shot.channel("irradiance", 2)
    report = inspect(tmp_path / "s")
    assert report["channel_frames"] == {"irradiance": [0, 3]} and not report["problems"]
    assert "irradiance is on the keyframes only: read there (the frames between hold G-buffer passes)" in report["notes"]


def test_light_with_gaps_where_rgb_has_none_is_still_an_error(tmp_path):
    with pytest.raises(ValueError, match=r"irradiance: gap in frame numbering"):
        load_shot(keyframe_folder(tmp_path, rgb_gaps=False))


def test_an_albedo_edit_on_a_filled_frame_moves_the_fill_by_the_filled_shading(tmp_path):
    shot = load_shot(keyframe_folder(tmp_path))
    scale = shot.info.irradiance_scale
    started, modes, frames = render(shot, RenderSettings(quality="formula"), patch_edit())
    assert started.tier == "formula" and "the base's shading" in started.reason
    on = np.zeros(shot.size, bool)
    on[BOX] = True
    reach = grow(on, SPILL_MARGIN)
    for t in range(4):
        albedo = shot.channel("albedo", t).astype(np.float64)
        if t in KEYS:  # the shot's own rgb and irradiance: rgb + (new - old albedo) x irradiance (no DiffCol pass here)
            base = shot.channel("rgb", t).astype(np.float64)
            light = shot.channel("irradiance", t).astype(np.float64) / scale
        else:  # the fill, and the shading it modulated
            fill = fill_frame(shot, t)
            assert fill.holes == 0 and fill.shading is not None
            base, light = fill.rgb.astype(np.float64), fill.shading.astype(np.float64)
        np.testing.assert_array_equal(frames[t][~reach], base[~reach], err_msg=f"frame {t} outside the edit's reach")
        want = np.maximum(base + (np.asarray(RED) - np.clip(albedo, 0, 1)) * light, 0)
        np.testing.assert_allclose(frames[t][on], want[on], rtol=1e-5, atol=1e-6, err_msg=f"frame {t} inside the edit")
        assert frames[t][on][:, 0].mean() > base[on][:, 0].mean() + 1.0, t  # visibly redder
        assert modes[t] == "formula", (t, modes[t])
    # a light edit of every frame: the frame times its gain, the filled ones too (a ratio over the base)
    e = Edits()
    e.ops.append(Exposure(stops=1.0))
    _, _, brighter = render(shot, RenderSettings(quality="formula"), e)
    for t in BETWEEN:
        np.testing.assert_allclose(brighter[t], 2 * fill_frame(shot, t).rgb, rtol=1e-5, atol=1e-5, err_msg=f"frame {t}")


def test_auto_does_not_generate_for_irradiance_on_the_keyframes_only(tmp_path):
    shot = load_shot(keyframe_folder(tmp_path))
    model = SimpleNamespace(residual_net=object(), residual_auto=True)
    over = registry.decide("auto", shot, patch_edit(), model)  # RenderSettings.base 'auto': over the base
    assert over.tier == "residual" and "missing" not in over.reason and "the base's shading" in over.reason, over
    plan = registry.plan_render(shot, patch_edit(), RenderSettings(quality="auto"), model)
    assert plan.tier == "residual"
    off = registry.decide("auto", shot, patch_edit(), model, base="off")  # no base: the frames between have no light
    assert off.tier == "diffusion" and "irradiance missing" in off.reason, off
    dropped = patch_edit()
    dropped.dropped.add("irradiance")  # dropped by the user: generated, base or not
    assert registry.decide("auto", shot, dropped, model).tier == "diffusion"
    # without irradiance anywhere (rgb/ with gaps and no irradiance/) the keyframes' own shading stands in too
    bare = load_shot(_without_irradiance(tmp_path))
    start, _, frames = render(bare, RenderSettings(quality="formula"), patch_edit())
    _, _, base = render(bare, RenderSettings(quality="formula"))
    assert start.tier == "formula"
    for t in range(4):
        red, blue = (frames[t][BOX][..., c].mean() - base[t][BOX][..., c].mean() for c in (0, 2))
        assert red > 1.0 and blue < -1.0, (t, red, blue)
    assert registry.decide("auto", load_shot(tmp_path / "s"), None, model).tier == "residual"


def _without_irradiance(tmp_path):
    import shutil

    shutil.rmtree(tmp_path / "s" / "irradiance")
    return tmp_path / "s"


def test_no_edit_keeps_the_base_and_reads_no_shading(tmp_path):
    shot = load_shot(keyframe_folder(tmp_path))
    started, modes, frames = render(shot, RenderSettings(quality="formula"))
    assert started.tier == BASE and set(modes.values()) == {BASE}
    for t in BETWEEN:
        np.testing.assert_array_equal(frames[t], fill_frame(shot, t).rgb)
