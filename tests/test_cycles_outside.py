"""The outside test scenes: one rendered tiny through the CLI and read back with the user's loader; material classes."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from x2video.channels import INTRINSIC
from x2video.cycles.classes import CLASSES, classify, material_classes

bpy_missing = subprocess.run([sys.executable, "-c", "import importlib.util,sys; sys.exit(importlib.util.find_spec('bpy') is None)"], check=False).returncode


@pytest.mark.slow
@pytest.mark.skipif(bool(bpy_missing), reason="bpy is not installed: `pip install -e '.[cycles]'` (scripts/setup.sh does)")
def test_outside_scene_renders_and_loads(tmp_path):
    from x2video.io import load_shot

    out = tmp_path / "outside"
    cmd = [sys.executable, "-m", "x2video", "dataset", "outside", "--scenes", "corridor", "--frames", "2", "--size", "48x32",
           "--samples", "4", "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    meta = json.loads((out / "dataset.json").read_text())
    assert meta["complete"] and meta["splits"]["test"] == ["test/corridor"]
    room = out / "test" / "corridor"
    shot = load_shot(room)
    assert shot.num_frames == 2 and shot.size == (32, 48)
    for ch in (*INTRINSIC, "rgb", "ids"):
        assert ch in shot.info.channels, ch
    assert shot.info.poses is not None and len(shot.info.poses) == 2
    assert not np.allclose(shot.info.poses[0].cam_to_world, shot.info.poses[1].cam_to_world), "the camera moves"
    extra = shot.info.extra
    assert extra["generator"] == "x2video.cycles.outside v1" and extra["scene"] == "corridor"
    classes = material_classes(json.loads((room / "shot.json").read_text()))
    assert {"glossy", "metal", "emitter", "diffuse"} <= set(classes.values())
    fr = shot.frame(1)
    ids = np.unique(fr["ids"])
    assert all(int(i) in classes for i in ids if i > 0), "every object id seen has a class"
    assert fr["irradiance"].mean() > 0 and fr["rgb"].max() > 0
    # the glossy floor is glossy in the roughness AOV too: 0.05 where the floor is
    floor = next(k for k, v in shot.info.object_captions.items() if "floor" in v)
    on_floor = fr["ids"][..., 0] == int(floor)
    assert on_floor.any() and np.median(fr["roughness"][on_floor]) == pytest.approx(0.05, abs=0.01)  # edge pixels are blends


def test_classify_and_material_classes():
    assert classify(roughness=0.5) == "diffuse" and classify(roughness=0.1) == "glossy"
    assert classify(roughness=0.0, metallic=1.0) == "metal" and classify(roughness=0.0, transmission=1.0) == "glass"
    assert classify(roughness=0.9, emission=3.0) == "emitter"
    assert material_classes({"extra": {"material_class": {"3": "metal", "4": "glass"}}}) == {3: "metal", 4: "glass"}
    with pytest.raises(ValueError):
        material_classes({"extra": {"material_class": {"3": "plastic"}}})
    with pytest.raises(ValueError):
        material_classes({"extra": {}})


def test_material_classes_of_a_procedural_cycles_room():
    """The procedural Cycles rooms are classed from their seed and path-traced extras (no bpy)."""
    from x2video.procedural.scene import generate_scene

    seed = 3000009
    scene = generate_scene(seed)
    floor = next(o.id for o in scene.objects if o.category == "floor")
    walls = next(o.id for o in scene.objects if o.category == "walls")
    other = next(o.id for o in scene.objects if o.category not in ("floor", "walls", "ceiling"))
    doc = {"extra": {"generator": "x2video.cycles v1", "room_seed": seed,
                     "path_traced": {"glossy_floor": 0.08, "metal": [[other, "brass"]], "mirror": True, "glass": True}}}
    got = material_classes(doc)
    assert got[floor] == "glossy" and got[other] == "metal" and got[walls] == "diffuse"
    assert got[max(o.id for o in scene.objects) + 1] == "metal"  # the mirror
    assert set(got.values()) <= set(CLASSES)


def test_a_build_of_some_splits_keeps_the_other_splits_rooms_listed(tmp_path):
    """`x2video dataset make --renderer cycles --splits val` on a set whose test rooms are already built: dataset.json
    lists the finished rooms of every split (it listed only the splits built last, and the test rooms vanished from it)."""
    from x2video.cycles.dataset import CyclesJob, finished_rooms
    from x2video.procedural.dataset import room_dir

    jobs = []
    for i in range(20):  # test_every 10: rooms 8 and 18 are validation rooms, 9 and 19 test rooms
        room = room_dir(tmp_path, i, 10, val=True)
        jobs.append(CyclesJob(i, i, str(room), 8, 16, 16, 4, outs=[str(room)]))
        if i in (8, 9, 19):  # finished: a test room from an earlier build, this build's validation room, another test room
            room.mkdir(parents=True)
            (room / "shot.json").write_text("{}")
    rooms, done = finished_rooms(jobs, tmp_path, 10)
    assert rooms == {"train": [], "val": ["val/room_00008"], "test": ["test/room_00009", "test/room_00019"]}
    assert [p.name for p in done] == ["room_00008", "room_00009", "room_00019"]
