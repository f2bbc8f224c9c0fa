"""Tiers (formula, tier-1 residual net, diffusion): auto's choices, forced tiers, the regional composite, the net itself."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from sampling_fake import FakeModel, make_shot

from x2video.edits import Edits
from x2video.edits.masks import Mask
from x2video.edits.model import Reference
from x2video.edits.ops import MaskOut
from x2video.formula import formula
from x2video.model import residual as R
from x2video.model import residual_engine
from x2video.render.events import FramesReady, RenderStarted, StepDone
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.shot import ArrayShot
from x2video.tiers import registry as tiers


def full_shot(num_frames: int = 5, h: int = 32, w: int = 48) -> ArrayShot:
    """`make_shot` plus roughness and metallic: all five channels."""
    base = make_shot(num_frames, h, w)
    rng = np.random.default_rng(1)
    arrays = {n: np.stack([base.channel(n, t) for t in range(num_frames)]) for n in base.channels}
    arrays["roughness"] = rng.uniform(0, 1, (num_frames, h, w, 1)).astype(np.float32)
    arrays["metallic"] = np.zeros((num_frames, h, w, 1), np.float32)
    return ArrayShot(arrays)


def render(model, shot, settings, edits=None):
    events = []
    Renderer(model).render(shot, edits, settings, events.append)
    frames = {}
    for e in events:
        if isinstance(e, FramesReady):
            frames.update(e.frames)
    return events, frames


def with_net(seed: int = 0) -> FakeModel:
    m = FakeModel()
    torch.manual_seed(seed)
    m.residual_net = R.ResidualNet(R.ResidualConfig(widths=(8, 16))).eval()
    torch.nn.init.normal_(m.residual_net.out.weight, std=0.1)  # not the zero init: the net must change frames
    return m


def test_choose_tier_says_why():
    assert tiers.choose_tier("auto", [], False, True).tier == "residual"
    assert tiers.choose_tier("auto", [], False, False).tier == "diffusion"  # no tier-1 net: the sampler, as before tiers
    c = tiers.choose_tier("auto", ["channel(s) irradiance missing or dropped"], False, True)
    assert c.tier == "diffusion" and "irradiance" in c.reason and not c.regions
    c = tiers.choose_tier("auto", ["albedo/material masked out (A|M|R) inside mask(s) m"], True, True)
    assert c.tier == "diffusion" and c.regions and c.base == "residual"
    assert tiers.choose_tier("formula", ["x"], False, False).tier == "formula"
    with pytest.raises(ValueError, match="tier-1 network"):
        tiers.choose_tier("residual", [], False, False)
    with pytest.raises(ValueError, match="unknown quality"):
        tiers.choose_tier("best", [], False, True)


def test_generation_reasons_from_edits():
    shot = full_shot()
    assert tiers.generation_reasons(shot, None) == ([], False)
    e = Edits()
    e.dropped = {"irradiance"}
    why, regions = tiers.generation_reasons(shot, e)
    assert "irradiance" in why[0] and not regions
    e = Edits()
    e.masks["m"] = Mask()
    e.ops.append(MaskOut(mask="m"))
    why, regions = tiers.generation_reasons(shot, e)
    assert regions and "A|M|R" in why[0]
    e.local_prompts["m"] = "a red sofa"
    why, regions = tiers.generation_reasons(shot, e)  # a local prompt acts inside its mask: still regional
    assert regions and len(why) == 2 and "local prompt" in why[1]
    e.ops.clear()
    assert tiers.generation_reasons(shot, e) == (["local prompt(s) on m"], True)
    e.dropped = {"irradiance"}  # a whole-frame reason: the sampler's frames everywhere
    assert tiers.generation_reasons(shot, e)[1] is False
    e.dropped = set()
    e.reference = Reference(frame=0)
    assert tiers.generation_reasons(shot, e)[1] is False


def test_auto_runs_the_residual_net_per_frame_deterministically():
    shot, model = full_shot(), with_net()
    events, frames = render(model, shot, RenderSettings())
    started = next(e for e in events if isinstance(e, RenderStarted))
    assert started.tier == "residual" and not any(isinstance(e, StepDone) for e in events)
    assert sorted(frames) == list(range(5))
    ch = shot.frame(2)
    x, f = R.features(ch)
    want = R.apply(model.residual_net, torch.from_numpy(x)[None], torch.from_numpy(f)[None])[0].permute(1, 2, 0).detach().numpy()
    np.testing.assert_allclose(frames[2], want, atol=1e-5)
    assert not np.allclose(frames[2], formula(ch), atol=1e-3)
    _, again = render(model, shot, RenderSettings())
    np.testing.assert_array_equal(again[2], frames[2])


def test_auto_renders_the_formula_when_only_channels_it_ignores_are_missing():
    shot, model = full_shot(), with_net()
    for dropped in ({"roughness"}, {"normal", "metallic"}):
        e = Edits()
        e.dropped = set(dropped)
        events, frames = render(model, shot, RenderSettings(), e)
        started = next(ev for ev in events if isinstance(ev, RenderStarted))
        assert started.tier == "formula" and "needs neither" in started.reason
        ch = shot.frame(1)
        np.testing.assert_allclose(frames[1], ch["albedo"] * ch["irradiance"], atol=1e-6)
        e.dropped |= {"irradiance"}  # the formula needs irradiance: generated
        assert next(ev for ev in render(model, shot, RenderSettings(steps=2), e)[0] if isinstance(ev, RenderStarted)).tier == "diffusion"
    e = Edits()
    e.dropped = {"roughness"}
    e.reference = Reference(frame=0)  # anything else that asks for generation still sends it to the sampler
    assert tiers.choose_tier("auto", tiers.generation_reasons(shot, e)[0], False, True, dropped=["roughness"]).tier == "diffusion"
    # forcing still works
    assert next(ev for ev in render(model, shot, RenderSettings(quality="diffusion", steps=2), Edits(dropped={"roughness"}))[0]
                if isinstance(ev, RenderStarted)).tier == "diffusion"


def test_forced_formula_and_diffusion():
    shot, model = full_shot(), with_net()
    _, f = render(model, shot, RenderSettings(quality="formula"))
    ch = shot.frame(3)
    np.testing.assert_allclose(f[3], ch["albedo"] * ch["irradiance"], atol=1e-6)
    events, _ = render(model, shot, RenderSettings(quality="diffusion", steps=2))
    assert any(isinstance(e, StepDone) for e in events)
    assert next(e for e in events if isinstance(e, RenderStarted)).tier == "diffusion"


def patch_edits(shot, name: str) -> Edits:
    """Edits with one mask `name` painted on rows 16:28, columns 24:40 of every frame (48x64 frames)."""
    e = Edits()
    m = np.zeros((48, 64), np.float32)
    m[16:28, 24:40] = 1
    e.masks[name] = Mask()
    for t in range(shot.num_frames):
        e.masks[name].paint(t, m)
    return e


def test_a_local_prompt_is_generated_inside_its_mask_and_the_rest_is_tier_1():
    """Masked Cross-Attention confines a local prompt to its mask, so auto keeps tier 1 around it (STABILITY.md measured
    29.4 dB outside a masked object with the composite, 23.0 with the sampler's whole frame)."""
    shot, model = full_shot(h=48, w=64), with_net()
    e = patch_edits(shot, "sofa")
    e.local_prompts["sofa"] = "a red leather sofa"
    events, frames = render(model, shot, RenderSettings(steps=2), e)
    started = next(x for x in events if isinstance(x, RenderStarted))
    assert started.tier == "diffusion" and "local prompt" in started.reason and "tier 1 around it" in started.reason
    _, tier1 = render(model, shot, RenderSettings(quality="residual"), e)
    _, whole = render(model, shot, RenderSettings(steps=2, quality="diffusion"), e)  # forced: the sampler's whole frame
    far = np.ones((48, 64), bool)
    far[16:28, 24:40] = False  # everywhere outside the mask: the seam lies inside it
    np.testing.assert_allclose(frames[1][far], tier1[1][far], atol=1e-5)
    np.testing.assert_allclose(frames[1][19:25, 27:37], whole[1][19:25, 27:37], atol=1e-5)  # the sampler's pixels 3 px in
    assert not np.allclose(whole[1][far], tier1[1][far], atol=1e-3)


def test_masked_region_is_generated_and_the_rest_is_tier_1():
    shot, model = full_shot(h=48, w=64), with_net()
    e = patch_edits(shot, "patch")
    e.ops.append(MaskOut(mask="patch"))
    events, frames = render(model, shot, RenderSettings(steps=2), e)
    assert next(x for x in events if isinstance(x, RenderStarted)).tier == "diffusion"
    _, tier1 = render(model, shot, RenderSettings(quality="residual"), e)  # tier 1 of the same edited channels
    far = np.ones((48, 64), bool)
    far[16:28, 24:40] = False  # everywhere outside the mask
    np.testing.assert_allclose(frames[1][far], tier1[1][far], atol=1e-5)
    assert not np.allclose(frames[1][16:28, 24:40], tier1[1][16:28, 24:40], atol=1e-3)
    # a net auto does not trust: the formula around the generated region, not the sampler on the whole frame
    model.residual_auto = False
    events, frames = render(model, shot, RenderSettings(steps=2), e)
    started = next(x for x in events if isinstance(x, RenderStarted))
    assert started.tier == "diffusion" and "formula around it" in started.reason
    _, tier0 = render(model, shot, RenderSettings(quality="formula"), e)
    np.testing.assert_allclose(frames[1][far], tier0[1][far], atol=1e-5)
    assert not np.allclose(frames[1][16:28, 24:40], tier0[1][16:28, 24:40], atol=1e-3)


def test_residual_net_any_size_zero_init_and_fp16_round_trip(tmp_path):
    net = R.ResidualNet(R.ResidualConfig(widths=(8, 16, 16)))
    shot = full_shot(1, 37, 53)
    x, f = R.features(shot.frame(0))
    y = R.apply(net, torch.from_numpy(x)[None], torch.from_numpy(f)[None])
    assert y.shape == (1, 3, 37, 53)
    np.testing.assert_allclose(y[0].permute(1, 2, 0).detach().numpy(), formula(shot.frame(0)), rtol=1e-5, atol=1e-6)
    torch.nn.init.normal_(net.out.weight, std=0.05)
    R.save(net, tmp_path / "w", {"note": "test"})
    assert json.loads((tmp_path / "w" / "residual.json").read_text())["config"]["widths"] == [8, 16, 16]
    back = R.load(tmp_path / "w")
    y1 = net(torch.from_numpy(x)[None, :, :32, :48])
    y2 = back(torch.from_numpy(x)[None, :, :32, :48])
    assert float((y1 - y2).abs().max()) < 1e-2  # fp16 weights


def test_train_residual_learns_and_resumes(tmp_path):
    from x2video.io import write_shot_folder
    from x2video.train.residual_stage import ResidualTrainConfig, train

    rng = np.random.default_rng(0)
    for split, n in (("train", 2), ("val", 1)):
        for i in range(n):
            t, h, w = 2, 32, 48
            al = rng.uniform(0.1, 0.9, (t, h, w, 3)).astype(np.float32)
            irr = rng.uniform(0.2, 1.0, (t, h, w, 3)).astype(np.float32)
            nrm = np.zeros((t, h, w, 3), np.float32)
            nrm[..., 2] = 1
            rough = rng.uniform(0, 1, (t, h, w, 1)).astype(np.float32)
            met = np.zeros((t, h, w, 1), np.float32)
            rgb = al * irr + 0.05 * (1 - rough)  # a "glossy" term the formula misses
            write_shot_folder(ArrayShot({"albedo": al, "irradiance": irr, "normal": nrm, "roughness": rough, "metallic": met, "rgb": rgb}),
                              tmp_path / "data" / split / f"s{i}")
    cfg = ResidualTrainConfig(steps=30, batch=2, crop=32, lr=3e-3, val_every=30, ckpt_every=15, widths=(8, 16))
    out = tmp_path / "run"
    s = train(tmp_path / "data", out, cfg, threads=1)
    assert s["steps"] == 30 and (out / "best" / "residual.safetensors").is_file()
    last = s["history"][-1]
    assert last["psnr"] > last["psnr_formula"]  # it learned some of the term the formula misses
    s2 = train(tmp_path / "data", out, ResidualTrainConfig(**{**cfg.__dict__, "steps": 40}), threads=1)
    assert s2["steps"] == 40 and len(s2["history"]) == 1  # resumed at 30, validated once at the end


def test_exposure_augmentation_scales_light_and_target_together(tmp_path):
    from x2video.train.residual_stage import NOISY_PLANES, Frames

    rng = np.random.default_rng(0)
    ch = {"albedo": rng.uniform(0.1, 0.9, (16, 16, 3)), "irradiance": rng.uniform(0.2, 2.0, (16, 16, 3)),
          "normal": np.dstack([np.zeros((16, 16, 2)), np.ones((16, 16))]), "roughness": rng.uniform(0, 1, (16, 16, 1)),
          "metallic": np.zeros((16, 16, 1))}
    x, shading = R.features({k: v.astype(np.float32) for k, v in ch.items()})
    y = 1.5 * shading  # target: a fixed multiple of the formula
    f = tmp_path / "s.npz"
    np.savez(f, x=x[None].astype(np.float16), y=y[None].astype(np.float16), scale=np.float32(1))
    xs, ys = Frames([f], exposure_aug=4.0).crops(np.random.default_rng(1), 16, 16)
    form = torch.expm1(xs[:, R.FORMULA_PLANES])
    gains = form.flatten(1).mean(1) / float(shading.mean())  # a flip keeps the mean
    assert torch.allclose(ys, 1.5 * form, rtol=0.03, atol=1e-3)  # target and formula planes moved together
    assert gains.min() < 0.6 and gains.max() > 1.6 and gains.max() <= 4.1 and gains.min() >= 0.24
    # the irradiance planes moved with the formula planes: albedo x irradiance is still the formula
    assert torch.allclose(xs[:, :3] * torch.expm1(xs[:, NOISY_PLANES][:, :3]), form, rtol=0.03, atol=2e-3)
    with pytest.raises(ValueError, match="exposure_aug"):
        Frames([f], exposure_aug=0.5)


def test_irradiance_dropout_gives_the_features_of_a_shot_without_irradiance(tmp_path):
    from x2video.train.residual_stage import Frames, drop_irradiance

    rng = np.random.default_rng(0)
    ch = {"albedo": rng.uniform(0.1, 0.9, (16, 16, 3)), "irradiance": rng.uniform(0.2, 2.0, (16, 16, 3)),
          "normal": np.dstack([np.zeros((16, 16, 2)), np.ones((16, 16))]), "roughness": rng.uniform(0, 1, (16, 16, 1)),
          "metallic": np.zeros((16, 16, 1))}
    ch = {k: v.astype(np.float32) for k, v in ch.items()}
    x, shading = R.features(ch)
    without, zero = R.features({**ch, "irradiance": None})
    assert not np.array_equal(x, without) and not zero.any()
    dropped = x.copy()
    drop_irradiance(dropped)
    np.testing.assert_array_equal(dropped, without)  # what the loaders give a shot with no irradiance pass
    f = tmp_path / "s.npz"
    np.savez(f, x=x[None].astype(np.float16), y=shading[None].astype(np.float16), scale=np.float32(1))
    xs, _ = Frames([f], irradiance_dropout=1.0).crops(np.random.default_rng(1), 4, 16)
    assert not xs[:, R.PRESENT_PLANES][:, 4].any() and not xs[:, 8:14].any() and xs[:, :3].any()
    xs, _ = Frames([f], irradiance_dropout=0.0).crops(np.random.default_rng(1), 4, 16)
    assert xs[:, R.PRESENT_PLANES][:, 4].all()


def test_onnx_engine_matches_pytorch():
    net = R.ResidualNet(R.ResidualConfig(widths=(8, 16, 16))).eval()
    torch.nn.init.normal_(net.out.weight, std=0.1)
    eng = residual_engine.engine(net, "cpu")
    assert isinstance(eng, residual_engine.OnnxResidual)
    shot = full_shot(1, 37, 53)
    x, f = (torch.from_numpy(a)[None] for a in R.features(shot.frame(0)))
    with torch.inference_mode():
        want = R.apply(net, x, f)
    got = R.apply(eng, x, f)
    assert got.shape == want.shape == (1, 3, 37, 53)
    assert float((got - want).abs().max()) < 1e-4  # stated parity: float32 on both sides
    assert residual_engine.engine(net, "cpu", prefer="torch") is net


def test_exported_form_of_the_net_equals_the_net():
    """The graphs are exported from `_Unconcatenated` (each decoder block's first conv split in two, no concatenation):
    the same function as the net for a whole frame, a tile with its context and a box, to float precision."""
    torch.manual_seed(3)
    net = R.ResidualNet(R.ResidualConfig(widths=(8, 16, 16))).eval()
    torch.nn.init.normal_(net.out.weight, std=0.3)
    form = residual_engine._Unconcatenated(net)
    x, g = torch.randn(2, net.cfg.in_channels, 24, 32), torch.randn(2, 16)
    others, cells = torch.randn(2, 16), torch.full((2, 1), 40.0)
    with torch.inference_mode():
        for got, want in ((form(x), net(x)), (form(x, g), net(x, g)), (form.forward_part(x, others, cells)[0], net.forward_part(x, others, cells)[0])):
            assert float(want.abs().max()) > 0.01  # a net that does something
            assert float((got - want).abs().max()) < 1e-5


def test_auto_keeps_the_formula_when_the_net_is_not_trusted():
    c = tiers.choose_tier("auto", [], False, True, residual_trusted=False)
    assert c.tier == "formula" and "validation rooms" in c.reason
    c = tiers.choose_tier("auto", ["albedo/material masked out (A|M|R) inside mask(s) m"], True, True, residual_trusted=False)
    assert c.tier == "diffusion" and c.regions and c.base == "formula"
    c = tiers.choose_tier("auto", ["irradiance dropped"], False, True, residual_trusted=False)
    assert c.tier == "diffusion" and not c.regions
    shot, model = full_shot(), with_net()
    model.residual_auto = False
    events, frames = render(model, shot, RenderSettings())
    assert next(e for e in events if isinstance(e, RenderStarted)).tier == "formula"
    ch = shot.frame(1)
    np.testing.assert_allclose(frames[1], ch["albedo"] * ch["irradiance"], atol=1e-6)
    assert tiers.choose_tier("residual", [], False, True, residual_trusted=False).tier == "residual"  # forcing still works


def test_tier1_keeps_the_formula_where_the_channels_hold_no_light():
    shot = full_shot(1, 16, 24)
    ch = {n: shot.channel(n, 0).copy() for n in shot.channels}
    ch["irradiance"][:4, :4] = 0  # clear glass: geometry, no diffuse light, not metal
    ch["irradiance"][:4, 8:12] = 0
    ch["metallic"][:4, 8:12] = 1  # a rough metal: no diffuse light either, but the net's reflection is kept
    ch["roughness"][:4, 8:12] = 0.4
    ch["irradiance"][:4, 16:20] = 0
    ch["metallic"][:4, 16:20] = 1  # a mirror: what it shows is elsewhere
    ch["roughness"][:4, 16:20] = 0.02
    ch["normal"][12:, :4] = 0  # sky: no geometry
    unseen = R.unseen_light(ch)
    assert unseen[:4, :4].all() and unseen[12:, :4].all() and unseen[:4, 16:20].all() and not unseen[:4, 8:12].any()
    assert unseen.mean() < 0.25
    arrays = {n: v[None] for n, v in ch.items()}
    m = with_net()
    _, kept = render(m, ArrayShot(arrays), RenderSettings(quality="residual"))
    _, guessed = render(m, ArrayShot(arrays), RenderSettings(quality="residual", guess_unseen=True))
    form = formula(ch)
    sky = np.s_[13:, :2]  # inside the sky patch, away from the grown edge
    assert np.allclose(kept[0][sky], form[sky]) and not np.allclose(guessed[0][sky], form[sky])
    assert np.allclose(kept[0][:4, 8:12], guessed[0][:4, 8:12])  # metal: the net's output either way
    assert np.allclose(kept[0][1:3, 17:19], form[1:3, 17:19])  # the mirror's inside keeps the formula
    assert np.allclose(kept[0][9:11, 12:16], guessed[0][9:11, 12:16])  # lit surfaces far from the patches: unchanged


def test_residual_features_clamp_roughness_and_metallic():
    rng = np.random.default_rng(0)
    ch = {"albedo": rng.uniform(0, 1, (8, 8, 3)).astype(np.float32), "normal": np.dstack([np.zeros((8, 8, 2)), np.ones((8, 8, 1))]).astype(np.float32),
          "roughness": np.full((8, 8, 1), 0.0, np.float32), "metallic": np.full((8, 8, 1), 1.0, np.float32),
          "irradiance": np.ones((8, 8, 3), np.float32)}
    hostile = {**ch, "roughness": np.full((8, 8, 1), -0.5, np.float32), "metallic": np.full((8, 8, 1), 3.0, np.float32)}
    assert np.array_equal(R.features(hostile)[0], R.features(ch)[0])


def test_a_toy_tier_is_one_new_class():
    """Adding a tier takes one class (`x2video.tiers.base`): the registry, `decide`, `plan_render` and `Renderer`
    (with no model, as it needs none) take it as they are."""
    from x2video.tiers.base import TIERS, PerFrameTier

    class HalfGreyTier(PerFrameTier):
        name = "toy-grey"
        needs_model = False
        channels = ()

        def frames(self, job, conds):
            return [np.full((*c.size, 3), 0.5, np.float32) for c in conds]

    try:
        shot = make_shot(5, 16, 24)
        settings = RenderSettings(frames=(1, 4))
        settings.quality = "toy-grey"  # the field's Literal lists the built-in tiers (the CLI's choices); the library takes any registered one
        assert tiers.plan_render(shot, None, settings, None).per_frame
        events, frames = render(None, shot, settings)
        started = next(e for e in events if isinstance(e, RenderStarted))
        assert started.tier == "toy-grey" and started.per_frame and sorted(frames) == [1, 2, 3]
        assert all(np.all(f == 0.5) for f in frames.values())
    finally:
        TIERS.pop("toy-grey", None)
    with pytest.raises(ValueError, match="unknown quality 'toy-grey'"):
        tiers.choose_tier("toy-grey", [], False, False)


def test_tiers_say_what_callers_used_to_compare_names_for():
    """The editor and the benches ask a tier what it is (`generative`, `with_preset`), never compare its name."""
    from x2video.render.settings import select_steps

    assert [n for n in tiers.QUALITIES if tiers.generative(n)] == ["diffusion"]
    assert not tiers.generative("") and not tiers.generative(None) and not tiers.generative("no-such-tier")
    fast = RenderSettings(preset="fast")
    assert tiers.get("diffusion").with_preset(fast, FakeModel()) == select_steps(fast, FakeModel())
    assert tiers.get("formula").with_preset(fast, FakeModel()) is fast and tiers.get("residual").with_preset(fast, None) is fast



def test_windowed_and_working_size_are_the_tiers_own():
    """`tiers.windowed` (the sampler's windows, steps and engine) and `Tier.working_size` (where a tier's network runs on a
    large frame) answer what the benches compared tier names for."""
    from x2video.conditioning.network import working_size

    assert [n for n in tiers.QUALITIES if tiers.windowed(n)] == ["diffusion"]
    assert not tiers.windowed("") and not tiers.windowed(None) and not tiers.windowed("no-such-tier")
    big, small = (1080, 1920), (224, 320)
    s = RenderSettings()
    model = FakeModel()
    model.residual_net = R.ResidualNet(R.ResidualConfig(widths=(8, 16))).eval()
    assert tiers.get("formula").working_size(big, s, None) is None
    assert tiers.get("residual").working_size(big, s, model) == working_size(big, model.residual_net.cfg.factor,
                                                                                      s.residual_pixels) is not None
    assert tiers.get("diffusion").working_size(big, s, model) == working_size(big, model.downsample, s.working_pixels) is not None
    assert all(tiers.get(n).working_size(small, s, model) is None for n in ("formula", "residual", "diffusion"))

def test_plan_render_is_what_the_render_runs():
    """`plan_render` (pure) names the tier and, for the diffusion tier, the windows and steps the render runs; the
    formula needs no model."""
    shot = make_shot(9)
    model = FakeModel(has_lcm=True)
    settings = RenderSettings(preset="fast", quality="diffusion")
    planned = tiers.plan_render(shot, None, settings, model)
    assert (planned.tier, planned.sampler, planned.steps, planned.per_frame) == ("diffusion", "lcm", 2, False)
    events, _ = render(model, shot, settings)
    started = next(e for e in events if isinstance(e, RenderStarted))
    assert started.num_windows == len(planned.windows) and list(planned.windows) == Renderer(model).plan(shot, settings)
    assert sum(planned.windows_per_level().values()) == len(planned.windows)
    assert sum(isinstance(e, StepDone) for e in events) == len(planned.windows) * planned.steps
    formula = tiers.plan_render(shot, None, RenderSettings(quality="formula"), None)
    assert formula.per_frame and formula.tier == "formula" and formula.windows == ()
    with pytest.raises(ValueError, match="needs a model"):
        tiers.plan_render(shot, None, RenderSettings(quality="diffusion"), None)


def test_a_tier_exact_in_part_renders_any_part_of_a_range_to_the_same_bytes():
    """`Tier.exact_in_part` (what lets `x2video render` resume a failed render with only the missing frames) holds
    for the formula; the tiers that batch frames or run windows do not claim it."""
    from x2video.tiers.base import TIERS

    assert TIERS["formula"].exact_in_part and not TIERS["residual"].exact_in_part and not TIERS["diffusion"].exact_in_part
    shot = full_shot(6)
    _, whole = render(None, shot, RenderSettings(quality="formula"))
    _, part = render(None, shot, RenderSettings(quality="formula", frames=(2, 5)))
    assert sorted(part) == [2, 3, 4] and all(np.array_equal(part[t], whole[t]) for t in part)


def test_the_composite_seam_lies_inside_the_generated_region():
    """auto's regional composite: tier 2's weight is 0 outside the region, 1 deeper than SEAM_PX inside, a linear ramp
    between (so the surfaces around a masked object keep tier 1's frame untouched)."""
    from x2video.tiers.regions import SEAM_PX, composite_weight

    m = np.zeros((40, 40), bool)
    m[10:30, 5:35] = True
    w = composite_weight(m)
    assert w.dtype == np.float32 and not w[~m].any()
    assert np.all(w[10 + int(SEAM_PX):30 - int(SEAM_PX), 5 + int(SEAM_PX):35 - int(SEAM_PX)] == 1)
    assert w[20, 5] == pytest.approx(1 / SEAM_PX, abs=1e-6) and w[20, 6] == pytest.approx(min(1, 2 / SEAM_PX), abs=1e-6)  # the edge ramps in
    assert 0 < w[20, 5] < 1  # a ramp, not a hard edge
    assert np.all(np.diff(w[20, 5:20]) >= 0)
    assert not composite_weight(np.zeros((8, 8), bool)).any() and np.all(composite_weight(np.ones((8, 8), bool), 0) == 1)


def test_the_seam_width_is_read_at_call_time_and_a_negative_one_feathers_outward(monkeypatch):
    """bench.pathtraced --seam-px sets regions.SEAM_PX to choose the width on validation rooms: composite_weight reads it
    when called; a negative width is the earlier rule (the sampler's frame feathered that many pixels outward)."""
    from x2video.tiers import regions

    m = np.zeros((40, 40), bool)
    m[10:30, 5:35] = True
    monkeypatch.setattr(regions, "SEAM_PX", 6.0)
    assert regions.composite_weight(m)[20, 5] == pytest.approx(1 / 6, abs=1e-6)
    out = regions.composite_weight(m, -6.0)
    assert np.array_equal(out, regions.feathered(m, 6.0)) and out[20, 3] > 0 and np.all(out[m] == 1)
