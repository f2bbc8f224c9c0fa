"""bench.edits end to end on a tiny Cycles room: rendered before and after an albedo edit, scored by every method that
needs no network; and its pure parts (target picking, the edit in x2video's terms, region scores) on arrays."""
import json
import subprocess
import sys

import numpy as np
import pytest

bpy_missing = subprocess.run([sys.executable, "-c", "import importlib.util,sys; sys.exit(importlib.util.find_spec('bpy') is None)"]).returncode

SEED = 43000129  # bench.clips' validation room: its largest furniture is a diffuse cabinet, its floor glossy


def test_pick_targets_takes_the_largest_object_of_each_kinds_class():
    from bench.edits_data import COLOURS, pick_targets

    ids = np.zeros((2, 20, 30), np.int32)
    ids[:, :10] = 1  # floor, glossy
    ids[:, 10:, :12] = 5  # a diffuse sofa, larger than the chair
    ids[:, 10:, 12:20] = 6  # a diffuse chair
    ids[:, 10:, 20:] = 7  # a metal lamp
    albedo = np.full((2, 20, 30, 3), 0.8, np.float32)
    albedo[ids == 5] = (0.8, 0.05, 0.05)  # red already: the recolour takes another colour
    classes = {1: "glossy", 5: "diffuse", 6: "diffuse", 7: "metal"}
    cats = {1: "floor", 5: "sofa", 6: "chair", 7: "floor lamp"}
    picks = pick_targets(ids, albedo, classes, cats, {5: "a red sofa"})
    assert picks["albedo"]["target"]["id"] == 5 and picks["albedo"]["target"]["caption"] == "a red sofa"
    assert tuple(picks["albedo"]["look"]["color"]) != COLOURS[0]
    assert picks["rough"]["look"] == {"kind": "rough", "id": 1, "value": 0.6}  # the glossy floor made rough
    assert picks["gloss"]["target"]["id"] == 5 and picks["metal_on"]["target"]["id"] == 5
    assert picks["metal_off"]["look"] == {"kind": "metal_off", "id": 7, "value": 0.0}
    assert picks["light"]["look"]["kind"] == "light"
    del classes[7]  # no metal in the room: that kind is skipped
    assert pick_targets(ids, albedo, classes, cats, {})["metal_off"] is None


def test_the_edit_in_x2video_terms_loads_and_selects_the_object():
    from bench.edits_data import x2video_edits
    from x2video.edits.model import Edits
    from x2video.edits.ops import AlbedoSet, LightTint, ScalarOp

    e = Edits.from_dict(x2video_edits({"kind": "albedo", "id": 12, "color": [0.8, 0.04, 0.03]}))
    (mask,) = e.masks.values()
    assert mask.ids == [12] and isinstance(e.ops[0], AlbedoSet) and e.ops[0].color == (0.8, 0.04, 0.03)
    e = Edits.from_dict(x2video_edits({"kind": "metal_off", "id": 3, "value": 0.0}))
    assert isinstance(e.ops[0], ScalarOp) and (e.ops[0].target_channel, e.ops[0].value) == ("metallic", 0.0)
    e = Edits.from_dict(x2video_edits({"kind": "light", "scale": 0.5, "tint": [1.0, 0.8, 0.6]}))
    assert isinstance(e.ops[0], LightTint) and e.ops[0].mask is None and e.ops[0].color == pytest.approx((0.5, 0.4, 0.3))


def test_a_room_without_metal_scores_metal_off_on_the_metal_on_pair_reversed(tmp_path):
    from bench.edits import edit_pair
    from bench.edits_data import x2video_edits
    from x2video.edits.model import Edits
    from x2video.edits.ops import ScalarOp
    from x2video.io import write_shot_folder
    from x2video.shot import ArrayShot

    ids = np.zeros((1, 8, 10, 1), np.float32)
    ids[:, 2:6, 3:7] = 6
    metallic = np.zeros((1, 8, 10, 1), np.float32)
    write_shot_folder(ArrayShot({"albedo": np.full((1, 8, 10, 3), 0.5, np.float32), "ids": ids, "metallic": metallic}),
                      tmp_path / "before")
    (tmp_path / "before" / "cycles.json").write_text(json.dumps({"frames": {"0": 9.0}, "beauty": {"0": [7.0, 7.5]}}))
    assert edit_pair(tmp_path, "metal_off") is None  # neither pair rendered
    on = {"kind": "metal_on", "target": {"id": 6, "caption": "a sofa"}, "look": {"kind": "metal_on", "id": 6, "value": 1.0},
          "edits": x2video_edits({"kind": "metal_on", "id": 6, "value": 1.0}), "cycles": {"seconds_per_frame": 8.0}}
    (tmp_path / "after_metal_on").mkdir()
    (tmp_path / "after_metal_on" / "edits.json").write_text(json.dumps(on))
    shot, truth, doc = edit_pair(tmp_path, "metal_off")
    assert (shot, truth) == (tmp_path / "after_metal_on", tmp_path / "before") and doc["reversed"]
    e = Edits.from_dict(doc["edits"])
    assert isinstance(e.ops[0], ScalarOp) and (e.ops[0].target_channel, e.ops[0].value) == ("metallic", 0.0)
    assert doc["cycles"]["seconds_per_frame"] == 7.0  # the truth's picture alone, as Cycles rendered it
    assert edit_pair(tmp_path, "metal_on")[:2] == (tmp_path / "before", tmp_path / "after_metal_on")


def test_region_scores_pool_the_squared_error_over_frames():
    from bench.edits import Scores, regions

    inside = np.zeros((20, 20), bool)
    inside[8:12, 8:12] = True
    m = regions(inside)
    assert m["inside"].sum() == 16 and not (m["band"] & m["inside"]).any() and not (m["outside"] & m["band"]).any()
    assert (m["inside"] | m["band"] | m["outside"]).all()
    gt = np.zeros((20, 20, 3))
    pred = gt.copy()
    pred[inside] = 0.1  # error only inside: 20 dB there, none outside
    sc = Scores()
    sc.add(pred, gt, m)
    sc.add(gt, gt, m)  # a second, perfect frame halves the pooled error
    p = sc.psnr()
    assert p["inside"] == pytest.approx(10 * np.log10(2 / 0.01)) and p["outside"] == 99.0 and p["band"] == 99.0


@pytest.mark.slow
@pytest.mark.skipif(bool(bpy_missing), reason="bpy is not installed: `pip install -e '.[cycles]'` (scripts/setup.sh does)")
def test_a_tiny_room_before_and_after_an_albedo_edit_is_scored(tmp_path):
    from bench.edits import main as edits_main
    from bench.edits_data import make_room
    from x2video.base.difference import grow
    from x2video.io.load import load_shot

    room = make_room(tmp_path / f"room_{SEED}", SEED, 2, 64, 48, samples=4, threads=1, kinds=("albedo",), log=lambda m: None)
    target = room["kinds"]["albedo"]["target"]
    assert target["category"] not in ("floor", "walls", "ceiling") and target["class"] in ("diffuse", "glossy")
    folder = tmp_path / f"room_{SEED}"
    doc = json.loads((folder / "after_albedo" / "edits.json").read_text())
    cyc = doc["cycles"]
    assert len(cyc["frame_seconds"]) == 2 and len(cyc["beauty_seconds"]) == 2  # the picture alone: first frames, timed
    assert cyc["seconds_per_frame"] == cyc["beauty_seconds_per_frame"] > 0
    before, after = load_shot(folder / "before"), load_shot(folder / "after_albedo")
    assert after.info.extra["light_gain"] == before.info.extra["light_gain"] and after.info.extra["look"]["kind"] == "albedo"
    oid = target["id"]
    for t in range(2):
        obj = before.channel("ids", t)[..., 0] == oid
        assert obj.any() and np.array_equal(before.channel("ids", t), after.channel("ids", t))
        # the after render's AOV holds the new colour on the object (its texture unlinked), the old one elsewhere
        assert np.allclose(np.median(after.channel("albedo", t)[obj], axis=0), doc["look"]["color"], atol=0.01)  # edges: mixed
        far = ~grow(obj, 6)
        assert np.abs(after.channel("albedo", t)[far] - before.channel("albedo", t)[far]).max() < 1e-2
        # the same light gain, seed and samples: away from the object the two renders agree
        assert np.abs(after.channel("rgb", t)[far] - before.channel("rgb", t)[far]).mean() < 0.01
    out = tmp_path / "res" / "edits.json"
    assert edits_main(["--root", str(tmp_path), "--seeds", str(SEED), "--kinds", "albedo", "--methods", "nothing,rebuild,base-formula",
                       "--out", str(out), "--threads", "1", "--picture", "albedo:base-formula"]) == 0
    res = json.loads(out.read_text())
    m = res["kinds"]["albedo"]["methods"]
    assert m["rebuild"]["inside"] > m["nothing"]["inside"] + 5  # the compositor's rebuild makes the recolour
    # tier 0's difference over the base is the compositor's rebuild (DiffCol taken off, the new colour put on)
    assert m["base-formula"]["inside"] == pytest.approx(m["rebuild"]["inside"], abs=0.02)
    assert m["base-formula"]["outside_bit_identical"] is True and m["base-formula"]["outside"] == m["nothing"]["outside"]
    assert m["base-formula"]["whole"] > m["nothing"]["whole"]
    assert "| base-formula |" in out.with_suffix(".md").read_text() and res["picture"]["file"] == "edits.png"
    assert out.with_suffix(".png").stat().st_size > 1000
