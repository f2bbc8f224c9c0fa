"""End to end through the Blender add-on (its test scene, tests/test_blender_addon.py), tiny Cycles renders:

- issue 52: an albedo edit over a Cycles shot's base (tier 0) is the compositor's rebuild from the EXR's own planes
  inside the edited object, Combined - DiffCol x (DiffDir + DiffInd) + colour x (DiffDir + DiffInd), and the shot's
  Combined bit for bit outside the edit's reach;
- issue 51: a keyframe clip is filled under every quality the registry offers (keyframes the shot's rgb, frames
  between filled from them, nearer the path-traced truth than either keyframe), every tier runs over that base with an
  edit, and the learned fill (fill tier 1) trains one step on the same clip rendered in full and fills the clip;
- both: an albedo edit of that clip under tier 0 is the compositor's rebuild on its keyframes (their light passes,
  read there) and the fill + (new albedo - old albedo) x the filled shading on the frames between.
"""
from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
from test_blender_addon import RUNNERS, export, object_id

from x2video.base.difference import SPILL_MARGIN, grow
from x2video.base.stage import BASE
from x2video.channels import tonemap
from x2video.edits import Edits
from x2video.edits.masks import Mask
from x2video.edits.ops import AlbedoSet
from x2video.io import load_shot
from x2video.io.image import read_image
from x2video.io.units import OutputUnits
from x2video.metrics.image import psnr
from x2video.render.events import FramesReady, RenderStarted
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.tiers.registry import qualities

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("torch_one_thread")]

#: the colour the slab is recoloured to: saturated, so that every channel of the change shows
RED = (0.9, 0.05, 0.05)
#: the keyframe clip's keyframes (5 frames, a keyframe every 2) and the frames the base fills between them
KEYS, BETWEEN = (0, 2, 4), (1, 3)


def slab_edit(out) -> Edits:
    """The slab (by its object id in the shot's ids channel) recoloured to `RED`."""
    e = Edits()
    e.masks["slab"] = Mask(ids=[object_id(out, "slab")])
    e.ops.append(AlbedoSet(mask="slab", color=RED))
    return e


def render(shot, settings: RenderSettings, edits=None, model=None) -> tuple[RenderStarted, set[str], dict[int, np.ndarray]]:
    """(the RenderStarted event, the modes of the FramesReady events, frame -> rgb in the shot's input units)."""
    events: list = []
    Renderer(model).render(shot, edits, settings, events.append)
    units = OutputUnits.for_shot(shot)
    frames = {t: units.scene(f) for e in events if isinstance(e, FramesReady) for t, f in e.frames.items()}
    return next(e for e in events if isinstance(e, RenderStarted)), {e.mode for e in events if isinstance(e, FramesReady)}, frames


def planes(path, name: str) -> np.ndarray:
    """(H, W, 3) float64 pass `name` of one of the add-on's EXR frames, read straight from the file."""
    img = read_image(path)
    return np.stack([img.planes[f"{name}.{c}"] for c in "RGB"], -1).astype(np.float64)


@pytest.mark.parametrize("runner", RUNNERS)
def test_albedo_edit_over_a_cycles_base_is_the_compositors_rebuild(tmp_path, runner):
    out = export(tmp_path, runner)  # 2 frames, every one a full render
    shot = load_shot(out)
    assert shot.info.irradiance_scale != 1.0  # the loader normalised the light: the frames' units matter below
    started, modes, frames = render(shot, RenderSettings(quality="formula"), slab_edit(out))  # base: "auto"
    assert started.tier == "formula" and "over the shot's path-traced frames" in started.reason and modes == {"formula"}
    slab = object_id(out, "slab")
    for t in range(shot.num_frames):
        exr = out / f"frame_{t:04d}.exr"
        combined, diffcol = planes(exr, "Combined"), planes(exr, "DiffCol")
        light = planes(exr, "DiffDir") + planes(exr, "DiffInd")
        got = frames[t].astype(np.float64)
        on = shot.channel("ids", t)[..., 0] == slab
        reach = grow(on, SPILL_MARGIN)
        assert on.sum() >= 50 and (~reach).sum() > on.size // 2, (t, on.sum(), reach.sum())
        # outside the edit's reach: the exported Combined, bit for bit, in the input's units
        np.testing.assert_array_equal(got[~reach], combined[~reach], err_msg=f"frame {t} outside the edit")
        # inside: the compositor's rebuild from the EXR's planes (DiffCol, not the basecolor AOV, taken off), floored
        # at 0 as every render over the base is (Combined and the light passes are denoised apart, so it can dip below)
        want = np.maximum(combined - diffcol * light + np.asarray(RED) * light, 0.0)
        np.testing.assert_allclose(got[on], want[on], rtol=1e-5, atol=1e-5, err_msg=f"frame {t} inside the edit")
        r, b = got[on].mean(0)[[0, 2]], combined[on].mean(0)[[0, 2]]
        assert r[0] > b[0] + 0.05 and r[1] < b[1] - 0.05, (t, r, b)  # redder, less blue than the slab's own (0.2, 0.4, 0.6)


# ------------------------------------------------------------------------------------------------ issue 51
@pytest.fixture(scope="module", params=RUNNERS)
def clip(request, tmp_path_factory):
    """The test scene's 5 frames exported twice: as a keyframe shot (keyframe every 2: full renders on 0, 2, 4, G-buffer
    passes on 1, 3) and in full (keyframe every 1: every frame a keyframe), the path-traced truth of the frames between."""
    root = tmp_path_factory.mktemp("clip")
    (root / "keyed").mkdir()
    (root / "full").mkdir()
    return export(root / "keyed", request.param, keyframe_every=2), export(root / "full", request.param, keyframe_every=1)


@pytest.fixture(scope="module")
def model():
    from x2video.weights import load_model, shipped_weights

    if shipped_weights() is None:
        pytest.skip("no shipped weights in resources/ (the diffusion and residual tiers need them)")
    return load_model(device="cpu")


def display_psnr(a: np.ndarray, b: np.ndarray) -> float:
    return psnr(tonemap(a), tonemap(b))


def test_keyframe_clip_is_filled_under_every_quality_and_every_tier_renders_over_it(clip, model):
    keyed_dir, full_dir = clip
    keyed, full = load_shot(keyed_dir), load_shot(full_dir)
    assert keyed.keyframes == KEYS and full.keyframes == tuple(range(5)) and full.info.rgb_frames is None
    truth = {t: full.channel("rgb", t) for t in range(5)}
    fill = None
    for quality in qualities():  # no edits: every quality keeps the base, and no model is needed
        started, modes, frames = render(keyed, RenderSettings(quality=quality))
        assert started.tier == BASE and "3 keyframes of 5 frames, the rest filled" in started.reason and modes == {BASE}, quality
        assert sorted(frames) == list(range(5))
        for t in KEYS:
            np.testing.assert_array_equal(frames[t], keyed.channel("rgb", t), err_msg=f"{quality}: keyframe {t}")
        for t in BETWEEN:
            f, before, after = frames[t], keyed.channel("rgb", t - 1), keyed.channel("rgb", t + 1)
            assert np.isfinite(f).all() and (f >= 0).all(), (quality, t)
            assert not np.array_equal(f, before) and not np.array_equal(f, after), (quality, t)
            lo, hi = sorted((float(before.mean()), float(after.mean())))
            assert 0.8 * lo < f.mean() < 1.25 * hi, (quality, t, f.mean(), lo, hi)
            # reprojected from both keyframes: nearer the path-traced frame than holding either keyframe
            held = max(display_psnr(before, truth[t]), display_psnr(after, truth[t]))
            assert display_psnr(f, truth[t]) > held + 0.5, (quality, t, display_psnr(f, truth[t]), held)
        if fill is not None:  # one base: the quality changes nothing without edits
            for t in range(5):
                np.testing.assert_array_equal(frames[t], fill[t], err_msg=f"{quality}: frame {t}")
        fill = frames
    assert fill is not None
    # with an edit every tier runs over that base: outside the edit's reach every frame stays the base, bit for bit
    edits, slab = slab_edit(keyed_dir), object_id(keyed_dir, "slab")
    for quality in qualities():
        started, modes, frames = render(keyed, RenderSettings(quality=quality, steps=2, engine="torch"), edits, model)
        assert started.tier == quality or quality == "auto", (quality, started.tier)
        if quality == "auto":  # irradiance is on the keyframes only; the base supplies it between: nothing to generate
            assert started.tier != "diffusion" and "irradiance missing" not in started.reason, started
        for t in range(5):
            assert np.isfinite(frames[t]).all(), (quality, t)
            reach = grow(keyed.channel("ids", t)[..., 0] == slab, SPILL_MARGIN)
            np.testing.assert_array_equal(frames[t][~reach], fill[t][~reach], err_msg=f"{quality}: frame {t} outside the edit")
            if started.tier == "diffusion":  # the generated frame inside the edit's reach
                assert np.abs(frames[t][reach] - fill[t][reach]).max() > 1e-3, (quality, t)


def test_tier_0_recolours_the_slab_on_a_keyframe_shots_keyframes(clip):
    """The keyframes carry their light passes (DiffDir, DiffInd, DiffCol): the compositor's rebuild there, as on a shot
    rendered in full."""
    keyed_dir, _ = clip
    keyed = load_shot(keyed_dir)
    started, modes, frames = render(keyed, RenderSettings(quality="formula"), slab_edit(keyed_dir))
    assert started.tier == "formula" and modes == {"formula"}, (started, modes)
    slab = object_id(keyed_dir, "slab")
    for t in KEYS:
        on = keyed.channel("ids", t)[..., 0] == slab
        assert np.abs(frames[t][on] - keyed.channel("rgb", t)[on]).max() > 1e-3, f"keyframe {t}: the edit changed nothing"
        exr = keyed_dir / f"frame_{t:04d}.exr"
        combined, diffcol = planes(exr, "Combined"), planes(exr, "DiffCol")
        light = planes(exr, "DiffDir") + planes(exr, "DiffInd")
        want = np.maximum(combined - diffcol * light + np.asarray(RED) * light, 0.0)
        np.testing.assert_allclose(frames[t][on].astype(np.float64), want[on], rtol=1e-5, atol=1e-5, err_msg=f"keyframe {t}")


def test_tier_0_recolours_the_slab_on_the_filled_frames(clip):
    """Between keyframes no light pass exists: the fill's shading is the light, so the slab moves by (new albedo - old
    albedo) x the filled shading, and pixels outside the edit's reach stay the fill bit for bit."""
    from x2video.base.fill import fill_frame

    keyed_dir, _ = clip
    keyed = load_shot(keyed_dir)
    started, modes, frames = render(keyed, RenderSettings(quality="formula"), slab_edit(keyed_dir))
    assert "the base's shading" in started.reason, started.reason
    slab = object_id(keyed_dir, "slab")
    for t in BETWEEN:
        fill = fill_frame(keyed, t)
        assert fill.shading is not None
        on = keyed.channel("ids", t)[..., 0] == slab
        reach = grow(on, SPILL_MARGIN)
        assert on.sum() >= 50 and (~reach).sum() > on.size // 2, (t, on.sum())
        np.testing.assert_array_equal(frames[t][~reach], fill.rgb[~reach], err_msg=f"frame {t} outside the edit")
        albedo = np.clip(keyed.channel("albedo", t).astype(np.float64), 0, 1)
        want = np.maximum(fill.rgb + (np.asarray(RED) - albedo) * fill.shading, 0.0)
        np.testing.assert_allclose(frames[t][on].astype(np.float64), want[on], rtol=1e-5, atol=1e-5, err_msg=f"frame {t} inside")
        r, b = frames[t][on].mean(0)[[0, 2]], fill.rgb[on].mean(0)[[0, 2]]
        assert r[0] > b[0] + 0.05 and r[1] < b[1] - 0.05, (t, r, b)  # redder, less blue than the filled slab


def test_learned_fill_trains_a_step_on_the_clip_and_fills_it(clip, tmp_path, capsys):
    import torch

    from x2video.base.fill import fill_frame
    from x2video.base.learned import N_PLANES, fill_for_tier
    from x2video.cli import main as cli
    from x2video.model import fill_net as FN
    from x2video.train import fill_data as D
    from x2video.train.fill_stage import FillTrainConfig

    keyed_dir, full_dir = clip
    keyed, full = load_shot(keyed_dir), load_shot(full_dir)
    with pytest.raises(ValueError, match="rgb on every frame"):  # the data builder takes fully rendered shots only
        D.check_shot(keyed, str(keyed_dir))
    data, run = tmp_path / "data", tmp_path / "run"
    shutil.copytree(full_dir, data / "train" / "clip")
    rc = cli(["train", "fill", "--data", str(data), "--out", str(run), "--steps", "1", "--batch", "2", "--crop", "16",
              "--pool", "2", "--refresh", "0", "--threads", "1", "--lr", "0.05"])
    assert rc == 0 and "1 steps" in capsys.readouterr().out
    summary = json.loads((run / "results.json").read_text())["fill"]
    assert summary["steps"] == 1 and math.isfinite(summary["history"][-1]["loss"]) and summary["history"][-1]["loss"] > 0
    # the step moved the weights: the net `train` starts from (seeded; its output layer zero, the classical fill) is not
    # the one it saved
    torch.manual_seed(FillTrainConfig.seed)
    start = FN.FillNet(FN.FillNetConfig(in_channels=N_PLANES, widths=tuple(FillTrainConfig().widths))).state_dict()
    trained = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=False)["net"]
    assert set(start) == set(trained)
    moved = [k for k in start if not torch.equal(start[k], trained[k])]
    assert "out.weight" in moved and "out.bias" in moved, moved
    # fill tiers 0 (classical) and 1 (the weights just trained) on the keyframe clip
    learned = fill_for_tier(1, run / "best")
    assert fill_for_tier(0) is None
    for t in BETWEEN:
        classical, corrected = fill_frame(keyed, t).rgb, fill_frame(keyed, t, learned=learned).rgb
        assert np.isfinite(corrected).all() and (corrected >= 0).all() and not np.array_equal(corrected, classical), t
        truth = full.channel("rgb", t)
        assert abs(display_psnr(corrected, truth) - display_psnr(classical, truth)) < 3.0, t  # one step corrects a little
