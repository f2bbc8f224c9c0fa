"""Edits applied to a shot: each op changes the inside of its mask as specified and leaves the outside bit for bit."""
import copy

import numpy as np
import pytest

from x2video.channels import linear_to_srgb
from x2video.conditioning.edited import apply_edits, resolve_reference
from x2video.edits import AlbedoHSV, AlbedoSet, AlbedoTint, Edits, Exposure, LightTint, Mask, MaskOut, Reference, ScalarOp, op_from_dict
from x2video.io.image import write_ldr
from x2video.shot import ArrayShot

T, H, W = 3, 8, 10


@pytest.fixture
def shot():
    rng = np.random.default_rng(1)
    n = rng.normal(size=(T, H, W, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    ids = np.zeros((T, H, W), np.int32)
    ids[:, :4, :5] = 7
    return ArrayShot({
        "albedo": rng.uniform(0.05, 0.95, (T, H, W, 3)), "normal": n, "roughness": rng.random((T, H, W, 1)),
        "metallic": rng.random((T, H, W, 1)), "irradiance": rng.random((T, H, W, 3)) * 3, "ids": ids,
        "rgb": rng.random((T, H, W, 3)),
    })


def _edits(op):
    m = Mask()
    box = np.zeros((H, W), np.float32)
    box[2:6, 3:8] = 1
    m.paint(1, box)
    return Edits(masks={"box": m}, ops=[op]), box.astype(bool)


def _check(shot, op, name, expect):
    edits, inside = _edits(op)
    c = apply_edits(shot, edits, 1)
    base = shot.channel(name, 1)
    out = c.channels[name]
    assert np.array_equal(out[~inside], base[~inside])  # outside: bit for bit
    np.testing.assert_allclose(out[inside], expect(base)[inside], rtol=1e-5, atol=1e-6)
    for other in ("albedo", "normal", "roughness", "metallic", "irradiance"):
        if other != name:
            assert np.array_equal(c.channels[other], shot.channel(other, 1))
    return c


def test_albedo_ops(shot):
    _check(shot, AlbedoSet(mask="box", color=(0.2, 0.4, 0.6)), "albedo", lambda b: np.broadcast_to(np.float32([0.2, 0.4, 0.6]), b.shape))
    _check(shot, AlbedoTint(mask="box", color=(1.0, 0.5, 2.0)), "albedo", lambda b: np.clip(b * [1.0, 0.5, 2.0], 0, 1))
    _check(shot, AlbedoHSV(mask="box", hue=0.0, saturation=1.0, value=1.0), "albedo", lambda b: b)  # identity
    # a hue shift of 120 degrees rotates sRGB channels: pure-ish red -> green
    red = ArrayShot({"albedo": np.tile(np.float32([0.8, 0.1, 0.1]), (1, H, W, 1))})
    out = apply_edits(red, Edits(ops=[AlbedoHSV(hue=120.0)]), 0).channels["albedo"]
    np.testing.assert_allclose(linear_to_srgb(out)[0, 0], linear_to_srgb(np.float32([0.1, 0.8, 0.1])), atol=2e-3)
    half = apply_edits(red, Edits(ops=[AlbedoHSV(value=0.5)]), 0).channels["albedo"]
    np.testing.assert_allclose(linear_to_srgb(half)[0, 0], linear_to_srgb(np.float32([0.8, 0.1, 0.1])) * 0.5, atol=2e-3)


def test_scalar_and_light_ops(shot):
    for ch in ("roughness", "metallic"):
        _check(shot, ScalarOp(mask="box", target_channel=ch, mode="set", value=0.25), ch, lambda b: np.full_like(b, 0.25))
        _check(shot, ScalarOp(mask="box", target_channel=ch, mode="offset", value=0.3), ch, lambda b: np.clip(b + 0.3, 0, 1))
        _check(shot, ScalarOp(mask="box", target_channel=ch, mode="scale", value=0.5), ch, lambda b: b * 0.5)
    _check(shot, Exposure(mask="box", stops=-2.0), "irradiance", lambda b: b / 4)
    _check(shot, LightTint(mask="box", color=(1.0, 0.8, 0.5)), "irradiance", lambda b: b * [1.0, 0.8, 0.5])
    g = apply_edits(shot, Edits(ops=[Exposure(stops=1.0)]), 2)  # global
    np.testing.assert_allclose(g.channels["irradiance"], shot.channel("irradiance", 2) * 2)


def test_soft_mask_blends(shot):
    m = Mask()
    m.paint(0, np.full((H, W), 0.25, np.float32))
    c = apply_edits(shot, Edits(masks={"s": m}, ops=[ScalarOp(mask="s", target_channel="roughness", value=1.0)]), 0)
    np.testing.assert_allclose(c.channels["roughness"], 0.25 + 0.75 * shot.channel("roughness", 0), rtol=1e-6)


def test_mask_out_drop_and_prompts(shot):
    edits, inside = _edits(MaskOut(mask="box", channels=["albedo", "roughness"]))
    edits.dropped.add("normal")
    edits.global_prompt = "a room"
    edits.masks["sofa"] = Mask(ids=[7])
    edits.local_prompts = {"sofa": "red velvet", "box": "  "}
    c = apply_edits(shot, edits, 1)
    assert c.channels["normal"] is None
    assert (c.channels["albedo"][inside] == 0).all() and (c.channels["roughness"][inside] == 0).all()
    assert np.array_equal(c.channels["albedo"][~inside], shot.channel("albedo", 1)[~inside])
    assert np.array_equal(c.channels["metallic"], shot.channel("metallic", 1))
    assert np.array_equal(c.amr_mask, inside.astype(np.float32))
    assert edits.prompts().global_prompt == "a room" and edits.prompts().local == ["red velvet"]
    assert c.local_masks.shape == (1, H, W) and np.array_equal(c.local_masks[0], (shot.channel("ids", 1)[..., 0] == 7).astype(np.float32))
    # frame 0 has no painted box: nothing masked out there
    assert apply_edits(shot, edits, 0).amr_mask.sum() == 0


def test_apply_is_pure_and_checks_names(shot):
    edits, _ = _edits(AlbedoTint(mask="box", color=(0.5, 0.5, 0.5)))
    before = copy.deepcopy(edits)
    a0 = shot.channel("albedo", 1).copy()
    apply_edits(shot, edits, 1)
    assert edits == before and np.array_equal(shot.channel("albedo", 1), a0)
    edits.ops.append(Exposure(mask="nope", stops=1))
    with pytest.raises(ValueError, match=r"ops\[1\].*'nope' does not exist"):
        apply_edits(shot, edits, 1)
    with pytest.raises(ValueError, match="dropped: unknown channel"):
        apply_edits(shot, Edits(dropped={"albedoo"}), 0)


def test_mask_hold_and_rename(shot):
    m = Mask(hold=True)
    m.paint(1, np.ones((H, W)))
    assert m.at(shot, 0).all() and m.at(shot, 2).all()
    m.hold = False
    assert not m.at(shot, 2).any()
    e = Edits(masks={"a": m}, ops=[Exposure(mask="a", stops=1)], local_prompts={"a": "x"})
    e.rename_mask("a", "b")
    assert list(e.masks) == ["b"] and e.ops[0].mask == "b" and e.local_prompts == {"b": "x"}
    e.remove_mask("b")
    assert not e.masks and not e.ops and not e.local_prompts


def test_round_trip_dict(shot):
    edits, _ = _edits(AlbedoHSV(mask="box", hue=30, saturation=0.5))
    edits.ops += [ScalarOp(target_channel="metallic", mode="offset", value=-0.1), MaskOut(mask="box", channels=["metallic"])]
    edits.reference = Reference(frame=2)
    back = Edits.from_dict(edits.to_dict(), edits.mask_arrays())
    assert back == edits
    with pytest.raises(ValueError, match=r"edits\.ops\[0\]: unknown field\(s\) colour"):
        op_from_dict({"op": "albedo_set", "colour": [1, 0, 0]}, "edits.ops[0]")
    with pytest.raises(ValueError, match="unknown edit operation 'blur'"):
        op_from_dict({"op": "blur"})
    with pytest.raises(ValueError, match="mode"):
        op_from_dict({"op": "scalar", "mode": "pow"})


def test_reference(shot, tmp_path):
    assert resolve_reference(shot, Edits()) is None
    t, img = resolve_reference(shot, Edits(reference=Reference(frame=2)))
    assert t == 2 and np.array_equal(img, shot.channel("rgb", 2))
    big = np.zeros((40, 100, 3), np.float32)
    big[:, 25:75] = 1.0  # the centre crop to 8:10 keeps columns 25..75 only
    write_ldr(tmp_path / "ref.png", big)
    t, img = resolve_reference(shot, Edits(reference=Reference(path="ref.png")), base_dir=tmp_path)
    assert t == 0 and img.shape == (H, W, 3)
    np.testing.assert_allclose(img, 1.0, atol=1e-6)
    # a shot whose irradiance was normalised on load: its frame reference is in the model's exposure, as in training
    from x2video.io.image import write_exr

    scaled = ArrayShot({c: np.stack([shot.channel(c, k) for k in range(T)]) for c in shot.channels}, irradiance_scale=0.25)
    t, img = resolve_reference(scaled, Edits(reference=Reference(frame=2)))
    np.testing.assert_array_equal(img, shot.channel("rgb", 2) * np.float32(0.25))
    write_exr(tmp_path / "ref.exr", {c: np.full((H, W), 2.0, np.float32) for c in "RGB"}, "float")  # linear, the shot's units
    t, img = resolve_reference(scaled, Edits(reference=Reference(path="ref.exr")), base_dir=tmp_path)
    np.testing.assert_allclose(img, 0.5)
    t, img = resolve_reference(scaled, Edits(reference=Reference(path="ref.png")), base_dir=tmp_path)
    np.testing.assert_allclose(img, 1.0, atol=1e-6)  # a display picture: taken as it is
    with pytest.raises(ValueError, match="exactly one"):
        Reference()
    with pytest.raises(ValueError, match="missing.png: file does not exist"):
        resolve_reference(shot, Edits(reference=Reference(path=str(tmp_path / "missing.png"))))


def test_edits_api_by_mask_name(shot):
    """What an editor does to Edits, through its own methods: masks by name, tuning per target."""
    e = Edits()
    assert e.add_mask("sofa") == "sofa" and e.add_mask("sofa") == "sofa (2)"
    e.set_local_prompt("sofa", "blue velvet")
    e.set_local_prompt("sofa (2)", "   ")  # blank: no prompt
    assert e.local_prompts == {"sofa": "blue velvet"} and e.local_prompt("sofa (2)") == ""
    e.set_masked_out("sofa", True)
    e.set_masked_out("sofa", True)  # still one op
    assert e.masked_out("sofa") and not e.masked_out("sofa (2)") and len(e.ops) == 1
    with pytest.raises(KeyError, match="no mask 'chair'"):
        e.set_local_prompt("chair", "x")

    # tuning: one value per target, ops only for non-neutral values, colours given sRGB and stored linear
    e.set_tuning(None, "exposure", 1.5)
    e.set_tuning("sofa", "albedo_colour", (0.5, 0.5, 0.5))
    e.set_tuning("sofa", "roughness_mode", "set")
    e.set_tuning("sofa", "roughness", 0.2)
    assert e.tuning(None)["exposure"] == 1.5 and e.tuning(None)["albedo_colour"] is None
    sofa = e.tuning("sofa")
    assert sofa["albedo_colour"] == pytest.approx((0.5, 0.5, 0.5), abs=1e-5) and sofa["roughness"] == 0.2
    albedo = next(op for op in e.ops if isinstance(op, AlbedoSet))
    assert albedo.mask == "sofa" and albedo.color[0] == pytest.approx(0.214, abs=1e-3)  # sRGB 0.5, linear
    e.set_tuning("sofa", "roughness_mode", "none")  # back to neutral: its op goes, the value resets
    assert not any(isinstance(op, ScalarOp) for op in e.ops) and e.tuning("sofa")["roughness"] == 0.5
    with pytest.raises(KeyError, match="unknown tuning value 'hue_shift'"):
        e.set_tuning(None, "hue_shift", 1.0)
    kinds = [op.kind for op in e.ops]
    e.set_tuning("sofa", "hue", 30.0)  # the target's ops stay where its first one stood
    assert [op.kind for op in e.ops][: kinds.index("albedo_set") + 1] == kinds[: kinds.index("albedo_set") + 1]
    e.reset_tuning("sofa")
    assert [op.kind for op in e.ops] == ["mask_out", "exposure"]
    e.set_dropped("normal", True)
    e.set_dropped("irradiance", False)
    assert e.dropped == {"normal"}

    # a mask's frames and ids
    m = e.masks["sofa"]
    assert not m.painted(1, (H, W)).any()
    box = np.zeros((H, W), np.float32)
    box[2:4, 2:4] = 1
    m.set_painted(1, box)
    assert m.painted_frames() == [1] and np.array_equal(m.painted(1, (H, W)), box)
    m.set_painted(1, np.zeros((H, W)))  # an erased-away frame is no painted frame
    assert m.painted_frames() == []
    m.paint_frames({0: box, 2: box})
    m.add_id(7)
    m.add_id(7)
    assert m.painted_frames() == [0, 2] and m.ids == [7] and m.at(shot, 1)[0, 0] == 1.0  # id 7 covers [:4, :5]
    assert Edits.for_shot(shot).global_prompt == shot.info.caption
    assert Reference(path="x/look.png", at=3).describe() == "Image look.png (placed at frame 3)"
