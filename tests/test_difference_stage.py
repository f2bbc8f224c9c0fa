"""`x2video train difference` (x2video.train.difference_stage, .difference_data) on a tiny data set of rooms rendered
before and after an edit in bench.edits_data's layout, and the difference net's use: the loader picks
difference.safetensors, `ResidualTier` runs it for its difference over the base and nowhere else."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from x2video.edits import Edits
from x2video.edits.ops import AlbedoSet, ScalarOp
from x2video.io import write_shot_folder
from x2video.model import residual as R
from x2video.shot import ArrayShot

T, H, W = 2, 32, 48
OBJ = 5
BOX = (slice(10, 22), slice(16, 34))  # the object's pixels
WIDTHS = (8, 16)


def _edits(kind: str) -> dict:
    e = Edits()
    name = e.add_mask(f"object {OBJ}")
    e.masks[name].add_id(OBJ)
    if kind == "albedo":
        e.ops.append(AlbedoSet(mask=name, color=(0.8, 0.04, 0.03)))
    else:
        e.ops.append(ScalarOp(mask=name, target_channel="roughness", mode="set", value=0.9))
    return e.to_dict()


def write_room(folder: Path, seed: int, kinds=("albedo", "rough")) -> None:
    """A room in bench.edits_data's layout: before/ and after_<kind>/ with edits.json. The after render holds what the
    formula misses: a glossy term that falls with roughness and the new colour spilled onto the floor around the object."""
    rng = np.random.default_rng(seed)
    albedo = rng.uniform(0.2, 0.8, (T, H, W, 3)).astype(np.float32)
    irr = rng.uniform(0.5, 1.5, (T, H, W, 3)).astype(np.float32)
    normal = np.zeros((T, H, W, 3), np.float32)
    normal[..., 2] = 1
    rough = np.full((T, H, W, 1), 0.3, np.float32)
    ids = np.zeros((T, H, W, 1), np.float32)
    ids[:, BOX[0], BOX[1]] = OBJ
    chans = {"albedo": albedo, "irradiance": irr, "normal": normal, "roughness": rough, "metallic": np.zeros((T, H, W, 1), np.float32),
             "ids": ids}

    def render(al, ro):
        return al * irr + 0.2 * (1 - ro) * irr

    write_shot_folder(ArrayShot({**chans, "rgb": render(albedo, rough)}), folder / "before")
    near = np.zeros((H, W), bool)
    near[BOX[0].start - 3:BOX[0].stop + 3, BOX[1].start - 3:BOX[1].stop + 3] = True
    near[BOX] = False
    for kind in kinds:
        al, ro = albedo.copy(), rough.copy()
        if kind == "albedo":
            al[:, BOX[0], BOX[1]] = (0.8, 0.04, 0.03)
        else:
            ro[:, BOX[0], BOX[1]] = 0.9
        rgb = render(al, ro)
        if kind == "albedo":
            rgb[:, near] += 0.1 * np.array([0.8, 0.04, 0.03], np.float32) * irr[:, near]  # the spill
        after = folder / f"after_{kind}"
        write_shot_folder(ArrayShot({**chans, "albedo": al, "roughness": ro, "rgb": rgb}), after)
        (after / "edits.json").write_text(json.dumps({"kind": kind, "edits": _edits(kind)}))


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("pairs")
    write_room(root / "train" / "room_1", 1)
    write_room(root / "val" / "room_2", 2)
    return root


@pytest.fixture(scope="module")
def init(tmp_path_factory) -> Path:
    """A small tier-1 net to start from (not the zero init: its difference must change frames)."""
    torch.manual_seed(0)
    net = R.ResidualNet(R.ResidualConfig(widths=WIDTHS))
    torch.nn.init.normal_(net.out.weight, std=0.05)
    folder = tmp_path_factory.mktemp("init")
    R.save(net, folder)
    return folder


def test_pairs_are_found_complete_and_cached_as_the_stage_sees_them(data, tmp_path):
    from x2video.base.difference import reach, relit_metal
    from x2video.conditioning.edited import apply_edits
    from x2video.conditioning.frame import plain_conditioning
    from x2video.io.load import load_shot
    from x2video.train.difference_data import Pairs, cache_pairs, find_pairs

    partial = tmp_path / "train" / "room_3"
    shutil.copytree(data / "train" / "room_1", partial)
    (partial / "after_rough" / "edits.json").unlink()  # still rendering: not a pair yet
    assert [(p.room, p.kind) for p in find_pairs(tmp_path, "train", ("albedo", "rough"))] == [("room_3", "albedo")]
    assert find_pairs(data, "train", ("albedo",))[0].kind == "albedo"

    pairs = find_pairs(data, "val", ("albedo", "rough"))
    files = cache_pairs(pairs, tmp_path / "cache")
    assert files[0][0] == files[1][0]  # one before file for the room's pairs
    assert cache_pairs(pairs, tmp_path / "cache") == files  # cached once
    shot, after = load_shot(pairs[0].before), load_shot(pairs[0].after)
    s = float(shot.info.irradiance_scale)
    edits = Edits.from_dict(_edits("albedo"))
    with np.load(files[0][0]) as b, np.load(files[0][1]) as p:
        for t in range(T):
            o, e = plain_conditioning(shot, t), apply_edits(shot, edits, t)
            np.testing.assert_allclose(p["x"][t], R.features(relit_metal(o, e).channels)[0], rtol=2e-3, atol=1e-3)
            np.testing.assert_allclose(b["x"][t], R.features(o.channels)[0], rtol=2e-3, atol=1e-3)
            np.testing.assert_allclose(b["base"][t].transpose(1, 2, 0), shot.channel("rgb", t) * s, rtol=2e-3)
            np.testing.assert_allclose(p["target"][t].transpose(1, 2, 0), after.channel("rgb", t) * s, rtol=2e-3)
            np.testing.assert_array_equal(p["reach"][t], reach(o, e))
            assert p["inside"][t][BOX].all() and p["inside"][t].sum() == 12 * 18
            assert not p["glossy"][t].any()  # an albedo edit: the stage takes tier 0's rebuild, not tier 1
    with np.load(files[1][1]) as p:
        assert p["glossy"].any() and not (p["glossy"] & ~p["reach"]).any()  # a roughness edit: tier 1 inside its reach
    va = Pairs(files, [p.kind for p in pairs], scoring=True)
    assert len(va) == 2 * T


def test_the_validation_difference_is_the_tiers_difference_over_the_base(data, init, tmp_path):
    """What training and validation compute from the cache is what a render computes: tier 0's rebuild plus the net's
    residual over the formula (`residual_over_formula`) inside the reach, as `edited_frame` adds it under a difference
    net (features cached in float16: to half precision); and a net whose residual is nothing renders tier 0's frame."""
    from x2video.base.difference import reach
    from x2video.base.stage import edited_frame
    from x2video.base.tier1 import residual_over_formula
    from x2video.conditioning.edited import apply_edits
    from x2video.conditioning.frame import plain_conditioning
    from x2video.io.load import load_shot
    from x2video.train.difference_data import Pairs, cache_pairs, find_pairs
    from x2video.train.difference_stage import residual_over_formula as trained

    net = R.load(init)
    pairs = find_pairs(data, "val", ("albedo",))
    va = Pairs(cache_pairs(pairs, tmp_path / "cache"), ["albedo"], scoring=True)
    shot = load_shot(pairs[0].before)
    s = float(shot.info.irradiance_scale)
    for bf, pf, t, _, scale in va.frames:
        o, e = plain_conditioning(shot, t), apply_edits(shot, Edits.from_dict(_edits("albedo")), t)
        where = reach(o, e)
        base = shot.channel("rgb", t).astype(np.float64) * s
        want, mode = edited_frame(base, o, e, glossy_tier=True, residual=lambda ed, orig, w: residual_over_formula(net, orig, ed, w),
                                  learned=True)
        tier0, _ = edited_frame(base, o, e, glossy_tier=False, residual=None)
        nothing, _ = edited_frame(base, o, e, glossy_tier=True, residual=lambda ed, orig, w: (np.zeros_like(base), np.zeros_like(base)),
                                  learned=True)
        t32 = lambda a: torch.from_numpy(np.asarray(a, np.float32))[None]  # noqa: E731
        with torch.no_grad():
            got = (t32(pf["tier0"][t]) + trained(net, t32(pf["x"][t]), t32(pf["keep"][t])[:, None])
                   - trained(net, t32(bf["x"][t]), t32(bf["keep"][t])[:, None])).clamp_min(0)[0].permute(1, 2, 0).numpy()
        assert scale == s and mode == "formula+residual"
        np.testing.assert_allclose(got[where], want[where], rtol=5e-3, atol=5e-3)
        np.testing.assert_array_equal(nothing, tier0)  # no residual: the rebuild from the passes, bit for bit
        assert np.abs(want - tier0)[where].max() > 1e-3  # the net's residual difference is not nothing


def test_a_training_step_lowers_the_loss_on_a_repeated_batch(data, init, tmp_path):
    from x2video.train.difference_data import Pairs, cache_pairs, find_pairs
    from x2video.train.difference_stage import init_net, loss_fn, over_base
    from x2video.train.small_nets import optimiser_step

    pairs = find_pairs(data, "train", ("albedo", "rough"))
    tr = Pairs(cache_pairs(pairs, tmp_path / "cache"), [p.kind for p in pairs])
    net, folder = init_net(str(init))
    assert folder == init and net.training
    b = {k: torch.from_numpy(v) for k, v in tr.crops(np.random.default_rng(0), 4, 24, exposure_aug=2.0).items()}
    assert b["x_o"].shape == (4, R.BASE_PLANES, 24, 24) and b["reach"].shape == (4, 1, 24, 24) and (b["reach"].sum((1, 2, 3)) > 0).all()
    opt = torch.optim.AdamW(net.parameters(), lr=3e-3)
    losses = []
    assert float(loss_fn(over_base(net, b), b, 0.1)) == float(loss_fn(b["tier0"], b, 0.1))  # it starts at tier 0's frame
    for _ in range(30):
        loss = loss_fn(over_base(net, b), b, 0.1)
        assert torch.isfinite(loss)
        losses.append(float(loss.detach()))
        optimiser_step(net, opt, loss)
    assert max(losses[-3:]) < 0.85 * losses[0], losses  # from a zeroed output layer: slow for the first steps


def test_training_keeps_the_best_writes_what_it_learned_on_and_resumes(data, init, tmp_path):
    from x2video.train.difference_stage import DifferenceTrainConfig, train

    cfg = DifferenceTrainConfig(steps=2, batch=2, crop=24, val_every=1, ckpt_every=1, init=str(init), kinds="albedo,rough")
    out = tmp_path / "run"
    seen = []
    s = train(data, out, cfg, threads=1, progress=seen.append)
    assert s["steps"] == 2 and len(s["history"]) == 2 and len(seen) == 2
    doc = json.loads((out / "best" / "difference.json").read_text())
    assert (out / "best" / "difference.safetensors").is_file() and doc["config"]["widths"] == list(WIDTHS)
    assert doc["trained_on"]["train_rooms"] == ["room_1"] and doc["trained_on"]["val_pairs"] == {"albedo": 1, "rough": 1}
    base = doc["baseline"]
    for m in ("difference", "stage", "tier0", "formula", "nothing"):
        assert base[m]["reach"] is not None and set(base["by_kind"]) == {"albedo", "rough"}
    assert base["formula"]["inside"] > base["nothing"]["inside"]  # the albedo change itself: the formula has it
    back = R.load(out / "best", name="difference")
    assert back.cfg.widths == WIDTHS
    s2 = train(data, out, DifferenceTrainConfig(**{**cfg.__dict__, "steps": 3}), threads=1)
    assert s2["steps"] == 3 and len(s2["history"]) == 1 and s2["baseline"] == s["baseline"]  # resumed at 2
    assert json.loads((out / "results.json").read_text())["difference"]["steps"] == 3


def test_cli_flags_come_from_the_config(tmp_path):
    import argparse

    from x2video.cli.train import register
    from x2video.fields import from_args
    from x2video.train.difference_stage import DifferenceTrainConfig

    p = argparse.ArgumentParser()
    register(p.add_subparsers())
    a = p.parse_args(["train", "difference", "--data", "d", "--out", "o"])
    assert from_args(DifferenceTrainConfig, a) == DifferenceTrainConfig()
    a = p.parse_args(["train", "difference", "--data", "d", "--out", "o", "--minutes", "30", "--kinds", "albedo", "--whole-weight", "0.2"])
    assert from_args(DifferenceTrainConfig, a) == DifferenceTrainConfig(minutes=30.0, kinds="albedo", whole_weight=0.2)
    with pytest.raises(ValueError, match="kinds: paint"):
        from x2video.train.difference_data import parse_kinds

        parse_kinds("albedo,paint")


def test_the_loader_takes_difference_weights_beside_the_tier_1_net(tmp_path):
    from x2video.model.pipeline import X2VideoModel
    from x2video.model.residual_engine import torch_module, weights_sha
    from x2video.weights import shipped_weights

    shipped = shipped_weights()
    folder = tmp_path / "model"
    folder.mkdir()
    for f in ("config.json", "unet.safetensors", "vae.safetensors", "residual.safetensors", "residual.json"):
        (folder / f).symlink_to(shipped / f)
    assert X2VideoModel.from_pretrained(folder).difference_net is None
    net = R.load(shipped)
    torch.nn.init.normal_(net.out.weight, std=0.05)
    R.save(net, folder, {"note": "test"}, name="difference")
    m = X2VideoModel.from_pretrained(folder)
    assert m.difference_net is not None and weights_sha(torch_module(m.difference_net)) == weights_sha(R.load(folder, name="difference"))
    assert weights_sha(torch_module(m.difference_net)) != weights_sha(torch_module(m.residual_net))


def _renders(shot, edits, model, settings):
    from test_base_render import render

    from x2video.render.renderer import Renderer

    return render(shot, settings, edits, Renderer(model))[1]


def test_the_residual_tier_runs_the_difference_net_over_the_base_only():
    """With a difference net, an edit over the base changes inside its reach as that net's difference says; outside it the
    frame is the base bit for bit; a render of a shot without a base is tier 1's frame as before."""
    from test_base_render import BOX as EDIT
    from test_base_render import box_edit, room
    from test_tiers import with_net

    from x2video.base.difference import SPILL_MARGIN
    from x2video.io.units import OutputUnits
    from x2video.render.settings import RenderSettings

    shot, plain, with_diff = room(scale=0.5), with_net(0), with_net(0)
    with_diff.difference_net = with_net(1).residual_net
    e = box_edit()
    e.ops = [ScalarOp(mask="sofa", target_channel="roughness", value=0.9)]  # rougher: tier 1's difference (not sharpened)
    a, b = _renders(shot, e, plain, RenderSettings()), _renders(shot, e, with_diff, RenderSettings())
    same_net = with_net(0)
    same_net.difference_net = with_net(0).residual_net
    c = _renders(shot, e, same_net, RenderSettings())
    h, w = shot.size
    reach = np.zeros((h, w), bool)
    reach[EDIT[0].start - SPILL_MARGIN - 1:EDIT[0].stop + SPILL_MARGIN + 1, EDIT[1].start - SPILL_MARGIN - 1:EDIT[1].stop + SPILL_MARGIN + 1] = True
    units = OutputUnits.for_shot(shot)
    for t in a:
        np.testing.assert_array_equal(units.scene(b[t])[~reach], shot.channel("rgb", t)[~reach])
        np.testing.assert_array_equal(b[t][~reach], a[t][~reach])
        assert np.abs(b[t][EDIT] - a[t][EDIT]).max() > 1e-4  # another net's difference
        np.testing.assert_array_equal(c[t], a[t])  # the same weights: the same frames
    bare = room(rgb=False, scale=0.5)  # no base: tier 1 renders every frame, the difference net plays no part
    for settings in (RenderSettings(), RenderSettings(quality="residual")):
        x, y = _renders(bare, e, plain, settings), _renders(bare, e, with_diff, settings)
        for t in x:
            np.testing.assert_array_equal(x[t], y[t])
