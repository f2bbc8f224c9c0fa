"""Tier 0 over the base rebuilds the frame from Cycles' passes (x2video.base.passes): a Blender multi-layer shot's
DiffCol, glossy and emission terms are read as channels, an albedo edit over the base is the compositor's rebuild
(DiffCol, not the basecolor AOV, is what the diffuse light is taken off with), a light edit of every lamp is the base
times its gain (emitters and the sky included), and pixels no edit reaches stay the base bit for bit."""
from __future__ import annotations

import numpy as np
import pytest

from x2video.base.difference import SPILL_MARGIN, edited_frame, grow, light_only, sharpened
from x2video.base.passes import rebuild
from x2video.conditioning.edited import apply_edits
from x2video.conditioning.frame import plain_conditioning
from x2video.edits import Edits
from x2video.edits.masks import Mask
from x2video.edits.ops import AlbedoSet, Exposure, LightTint, ScalarOp
from x2video.io.image import write_exr
from x2video.io.load import load_shot
from x2video.shot import ArrayShot

H, W, T = 24, 32, 2
BOX = (slice(8, 16), slice(10, 22))  # the recoloured object
SKY = (slice(0, 4), slice(0, 8))  # a window onto the sky: emission, no irradiance


def passes_frame(rng: np.random.Generator) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """One Blender frame's planes (ViewLayer.<Pass>.<comp>) whose Combined is Cycles' split, and its terms. DiffCol is
    0.95 x the basecolor AOV (a dielectric's diffuse share), so the two factors give different rebuilds."""
    base = rng.uniform(0.2, 0.8, (H, W, 3)).astype(np.float32)
    diffcol = base * np.float32(0.95)
    light = {"DiffDir": rng.uniform(0.3, 1.0, (H, W, 3)), "DiffInd": rng.uniform(0.0, 0.3, (H, W, 3)),
             "GlossCol": rng.uniform(0.02, 0.1, (H, W, 3)), "GlossDir": rng.uniform(0.0, 2.0, (H, W, 3)),
             "GlossInd": rng.uniform(0.0, 0.5, (H, W, 3)), "TransCol": np.zeros((H, W, 3)), "TransDir": np.zeros((H, W, 3)),
             "TransInd": np.zeros((H, W, 3)), "Emit": np.zeros((H, W, 3)), "Env": np.zeros((H, W, 3))}
    light = {k: v.astype(np.float32) for k, v in light.items()}
    for k in ("DiffDir", "DiffInd", "GlossCol", "GlossDir", "GlossInd"):
        light[k][SKY] = 0
    light["Env"][SKY] = 4.0  # the sky seen through the window
    light["Emit"][2, 20:24] = (6.0, 5.0, 3.0)  # a lamp shade
    diffcol[SKY] = 0
    diffuse = diffcol * (light["DiffDir"] + light["DiffInd"])
    glossy = light["GlossCol"] * (light["GlossDir"] + light["GlossInd"])
    combined = diffuse + glossy + light["Emit"] + light["Env"]
    planes = {}
    for i, c in enumerate("RGB"):
        for name, v in {**light, "DiffCol": diffcol, "basecolor": base, "Combined": combined}.items():
            planes[f"ViewLayer.{name}.{c}"] = v[..., i]
    planes["ViewLayer.roughness.X"] = np.full((H, W), 0.5, np.float32)
    planes["ViewLayer.metallic.X"] = np.zeros((H, W), np.float32)
    ids = np.full((H, W), 1.0, np.float32)
    ids[BOX] = 7
    planes["ViewLayer.IndexOB.X"] = ids
    return planes, {"combined": combined, "diffcol": diffcol, "basecolor": base, "light": light["DiffDir"] + light["DiffInd"],
                    "glossy": glossy, "emission": light["Emit"] + light["Env"]}


@pytest.fixture(scope="module")
def blender_shot(tmp_path_factory):
    folder = tmp_path_factory.mktemp("blender")
    rng = np.random.default_rng(5)
    terms = []
    for t in range(T):
        planes, parts = passes_frame(rng)
        write_exr(folder / f"frame_{t:04d}.exr", planes, "float")  # the identities hold to float precision
        terms.append(parts)
    return load_shot(folder), terms


def object_edit(*ops) -> Edits:
    e = Edits()
    e.masks["cabinet"] = Mask(ids=[7])
    e.ops.extend(ops)
    return e


def test_blender_passes_load_as_the_split_of_combined(blender_shot):
    shot, terms = blender_shot
    assert {"diffuse_color", "glossy", "emission"} <= set(shot.channels)
    assert "GlossCol" in shot.info.extra["passes"]["glossy"] and shot.info.extra["passes"]["diffuse_color"] == "ViewLayer.DiffCol"
    s = shot.info.irradiance_scale
    for t in range(T):
        np.testing.assert_allclose(shot.channel("diffuse_color", t), terms[t]["diffcol"], atol=1e-6)
        np.testing.assert_allclose(shot.channel("glossy", t), terms[t]["glossy"], rtol=1e-6, atol=1e-6)  # GlossCol x (Dir + Ind)
        cond = plain_conditioning(shot, t)
        # the conditioning's passes are in the model's exposure: the rebuild of the unedited frame is Combined, scaled
        np.testing.assert_allclose(rebuild(cond, cond), shot.channel("rgb", t) * s, rtol=1e-5, atol=1e-6)


def test_an_albedo_edit_over_the_base_is_the_compositors_rebuild_with_diffcol(blender_shot):
    shot, terms = blender_shot
    colour = np.float32([0.85, 0.55, 0.02])
    edits = object_edit(AlbedoSet(mask="cabinet", color=tuple(colour)))
    s = shot.info.irradiance_scale
    for t in range(T):
        base = shot.channel("rgb", t).astype(np.float64) * s
        out, mode = edited_frame(base, plain_conditioning(shot, t), apply_edits(shot, edits, t), glossy_tier=False, residual=None)
        out = out / s
        assert mode == "formula"
        inside = np.zeros((H, W), bool)
        inside[BOX] = True
        # the compositor: Combined - DiffCol x light + colour x light on the object
        light = terms[t]["light"]
        want = terms[t]["combined"] - terms[t]["diffcol"] * light + colour * light
        np.testing.assert_allclose(out[inside], want[inside], rtol=1e-5, atol=1e-5)
        # the basecolor AOV as the factor would take off 1/0.95 of the diffuse light: a different, darker frame
        aov = terms[t]["combined"] - terms[t]["basecolor"] * light + colour * light
        assert np.abs(out[inside] - aov[inside]).min() > 1e-3
        far = ~grow(inside, SPILL_MARGIN)
        np.testing.assert_array_equal(out[far].astype(np.float32), shot.channel("rgb", t)[far])  # bit for bit


@pytest.mark.parametrize("op", [LightTint(color=(0.5, 0.425, 0.35)), Exposure(stops=-1.5)])
def test_a_light_edit_of_every_lamp_is_the_base_times_its_gain(blender_shot, op):
    """Every term scales with the lamps (glossy light and emission too): over the base as a ratio that is the base times
    the gain, the sky and the lamp shade included (no irradiance there: only the passes say the light changed)."""
    shot, _ = blender_shot
    gain = np.float32(op.color) if isinstance(op, LightTint) else np.float32(2.0 ** op.stops)
    s = shot.info.irradiance_scale
    for t in range(T):
        base = shot.channel("rgb", t).astype(np.float64) * s
        original, edited = plain_conditioning(shot, t), apply_edits(shot, object_edit(op), t)
        assert light_only(original, edited).all()
        out, _ = edited_frame(base, original, edited, glossy_tier=False, residual=None)
        np.testing.assert_allclose(out, base * gain, rtol=1e-6)
        # the same edit as a difference only adds the change of the rebuild: the ratio keeps what the passes miss
        off = base.copy()
        off[BOX] += 0.5  # light no pass holds, only in the base
        ratio, _ = edited_frame(off, original, edited, glossy_tier=False, residual=None)
        diff, _ = edited_frame(off, original, edited, glossy_tier=False, residual=None, mode="difference")
        np.testing.assert_allclose(ratio[BOX], off[BOX] * gain, rtol=1e-6)
        assert np.abs(diff[BOX] - off[BOX] * gain).min() > 0.1


def test_a_masked_light_edit_scales_the_passes_inside_its_mask_only(blender_shot):
    shot, _ = blender_shot
    edited = apply_edits(shot, object_edit(LightTint(mask="cabinet", color=(2.0, 2.0, 2.0))), 0)
    original = plain_conditioning(shot, 0)
    for name in ("glossy", "emission"):
        np.testing.assert_array_equal(edited.passes[name][BOX], original.passes[name][BOX] * 2)
        outside = np.ones((H, W), bool)
        outside[BOX] = False
        np.testing.assert_array_equal(edited.passes[name][outside], original.passes[name][outside])
    np.testing.assert_array_equal(edited.passes["diffuse_color"], original.passes["diffuse_color"])  # a colour, not light


def test_without_passes_the_rebuild_is_the_formula_and_emission_alone_still_scales():
    rng = np.random.default_rng(2)
    albedo = rng.uniform(0.1, 0.9, (1, H, W, 3)).astype(np.float32)
    irr = rng.uniform(0.5, 2.0, (1, H, W, 3)).astype(np.float32)
    irr[0][SKY] = 0
    emission = np.zeros_like(irr)
    emission[0][SKY] = 3.0
    shot = ArrayShot({"albedo": albedo, "irradiance": irr, "emission": emission, "rgb": albedo * irr + emission})
    cond = plain_conditioning(shot, 0)
    assert set(cond.passes) == {"emission"}
    np.testing.assert_allclose(rebuild(cond, cond), albedo[0] * irr[0] + emission[0], rtol=1e-6)
    edited = apply_edits(shot, object_edit(Exposure(stops=1.0)), 0)
    out, _ = edited_frame(shot.channel("rgb", 0).astype(np.float64), cond, edited, glossy_tier=False, residual=None)
    np.testing.assert_allclose(out, shot.channel("rgb", 0) * 2.0, rtol=1e-6)  # the sky doubles too


def test_sharpened_is_roughness_down_alone():
    rng = np.random.default_rng(4)
    shot = ArrayShot({"albedo": rng.uniform(0, 1, (1, H, W, 3)), "roughness": np.full((1, H, W, 1), 0.5),
                      "metallic": np.zeros((1, H, W, 1)), "irradiance": np.ones((1, H, W, 3))})
    ids = np.zeros((H, W), np.float32)
    ids[BOX] = 1
    original = plain_conditioning(shot, 0)

    def edit(*ops):
        e = Edits()
        e.masks["box"] = Mask(frames={0: ids}, hold=True)
        e.ops.extend(ops)
        return apply_edits(shot, e, 0)

    assert sharpened(original, edit(ScalarOp(mask="box", target_channel="roughness", value=0.05)))[BOX].all()
    assert not sharpened(original, edit(ScalarOp(mask="box", target_channel="roughness", value=0.9))).any()  # rougher: tier 1's
    both = edit(ScalarOp(mask="box", target_channel="roughness", value=0.05), ScalarOp(mask="box", target_channel="metallic", value=1.0))
    assert not sharpened(original, both).any()  # made metal too: tier 1's difference (the glossy change of a metal)


@pytest.fixture(scope="module")
def metal_shot(tmp_path_factory):
    """A Blender shot whose object (BOX) is a pure metal: DiffCol and the diffuse light passes black on it (no diffuse
    lobe), GlossCol its base colour; and the Cycles truth of it made non-metal, where the diffuse light is what the
    glossy lobe gathered (GlossDir + GlossInd) and GlossCol a dielectric's 0.04."""
    folder = tmp_path_factory.mktemp("metal")
    rng = np.random.default_rng(9)
    planes, parts = passes_frame(rng)
    base = parts["basecolor"]
    gloss_light = planes_of(planes, "GlossDir") + planes_of(planes, "GlossInd")
    metal_gc = np.clip(base, 0, 1)
    for name, v in (("DiffCol", 0.0), ("DiffDir", 0.0), ("DiffInd", 0.0)):
        for i, c in enumerate("RGB"):
            planes[f"ViewLayer.{name}.{c}"][BOX] = v
    for i, c in enumerate("RGB"):
        planes[f"ViewLayer.GlossCol.{c}"][BOX] = metal_gc[BOX][..., i]
        planes["ViewLayer.metallic.X"][BOX] = 1.0
    diffcol, light = planes_of(planes, "DiffCol"), planes_of(planes, "DiffDir") + planes_of(planes, "DiffInd")
    combined = diffcol * light + planes_of(planes, "GlossCol") * gloss_light + planes_of(planes, "Emit") + planes_of(planes, "Env")
    for i, c in enumerate("RGB"):
        planes[f"ViewLayer.Combined.{c}"] = combined[..., i]
    write_exr(folder / "frame_0000.exr", planes, "float")
    truth = combined.copy()
    truth[BOX] = (base * gloss_light + 0.04 * gloss_light)[BOX]  # non-metal: albedo x gathered light + 0.04 x glossy light
    return load_shot(folder), truth, combined


def planes_of(planes: dict[str, np.ndarray], name: str) -> np.ndarray:
    return np.stack([planes[f"ViewLayer.{name}.{c}"] for c in "RGB"], -1)


def test_a_metal_made_non_metal_is_rebuilt_from_the_glossy_passes(metal_shot):
    """Metallic edits over the base move light between the passes' terms (x2video.base.passes): the glossy term takes
    the dielectric's glossy colour, and the diffuse light the metal's black passes lack is the light its glossy lobe
    gathered (`relit_metal`); the rebuild renders the metal tier 0's (no tier-1 difference where the glossy colour pass
    is there), and the pixels no edit reaches stay the base."""
    shot, truth, combined = metal_shot
    assert "glossy_color" in shot.channels
    s = shot.info.irradiance_scale
    base = shot.channel("rgb", 0).astype(np.float64) * s
    original = plain_conditioning(shot, 0)
    edited = apply_edits(shot, object_edit(ScalarOp(mask="cabinet", target_channel="metallic", mode="set", value=0.0)), 0)
    calls = []
    out, mode = edited_frame(base, original, edited, glossy_tier=True, residual=lambda *a: calls.append(a))
    assert mode == "formula" and not calls  # the rebuild, not tier 1
    inside = np.zeros((H, W), bool)
    inside[BOX] = True
    np.testing.assert_allclose((out / s)[inside], truth[inside], rtol=1e-4, atol=1e-5)
    far = ~grow(inside, SPILL_MARGIN)
    np.testing.assert_array_equal((out / s).astype(np.float32)[far], shot.channel("rgb", 0)[far])
    assert np.abs((out / s)[inside] - combined[inside]).max() > 1e-2


def test_a_non_metal_made_metal_loses_its_diffuse_term_and_reflects_with_its_colour(blender_shot):
    shot, terms = blender_shot
    s = shot.info.irradiance_scale
    edits = object_edit(ScalarOp(mask="cabinet", target_channel="metallic", mode="set", value=1.0))
    inside = np.zeros((H, W), bool)
    inside[BOX] = True
    for t in range(T):
        base = shot.channel("rgb", t).astype(np.float64) * s
        out, mode = edited_frame(base, plain_conditioning(shot, t), apply_edits(shot, edits, t), glossy_tier=False, residual=None)
        gloss_light = terms[t]["glossy"] / np.maximum(shot.channel("glossy_color", t), 1e-3)
        want = terms[t]["emission"] + np.clip(terms[t]["basecolor"], 0, 1) * gloss_light  # DiffCol' = 0, GlossCol' = albedo
        np.testing.assert_allclose((out / s)[inside], want[inside], rtol=1e-4, atol=1e-5)
