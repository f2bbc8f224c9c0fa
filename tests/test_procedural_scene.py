"""Procedural rooms without rendering: sizes, openings, furniture placement, material families, lights, dataset CLI."""
from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from x2video.procedural.geometry import Part, part_mesh
from x2video.procedural.lighting import MOODS
from x2video.procedural.materials import FAMILIES
from x2video.procedural.scene import generate_scene

SEEDS = range(60)


@pytest.fixture(scope="module")
def scenes():
    return [generate_scene(s) for s in SEEDS]


def test_rooms_have_the_sizes_openings_and_shell_asked_for(scenes):
    for sc in scenes:
        assert 3 <= sc.width <= 8 and 3 <= sc.depth <= 8 and 2.5 <= sc.height <= 3.2
        kinds = Counter(o.kind for o in sc.openings)
        assert kinds["door"] == 1 and 1 <= kinds["window"] <= 2
        cats = [o.category for o in sc.objects]
        assert cats[:3] == ["floor", "walls", "ceiling"] and "door" in cats and "window" in cats
        assert [o.id for o in sc.objects] == list(range(1, len(sc.objects) + 1))


def test_variety_of_categories_families_moods(scenes):
    cats = Counter(o.category for sc in scenes for o in sc.objects)
    furniture = set(cats) - {"floor", "walls", "ceiling", "door", "window", "ceiling light"}
    assert len(furniture) >= 10, furniture
    fams = {m.family for sc in scenes for m in sc.materials}
    assert len(fams & set(FAMILIES)) >= 8, fams
    for sc in scenes:
        for m in sc.materials:
            if m.family in FAMILIES:
                lo, hi = FAMILIES[m.family].roughness
                assert lo <= m.roughness <= hi
    patterns = {m.pattern for sc in scenes for m in sc.materials}
    assert {"planks", "tiles", "stripes", "noise"} <= patterns
    assert len({sc.lighting.mood for sc in scenes}) == len(MOODS)
    assert all(sc.lighting.points or sc.lighting.sun for sc in scenes)  # every room has a light source


def test_furniture_footprints_do_not_overlap(scenes):
    for sc in scenes:
        rects = sc.obstacles
        for i, a in enumerate(rects):
            assert a[0] >= -1e-9 and a[1] >= -1e-9 and a[2] <= sc.width + 1e-9 and a[3] <= sc.depth + 1e-9
            for b in rects[i + 1:]:
                overlap = min(a[2], b[2]) - max(a[0], b[0]), min(a[3], b[3]) - max(a[1], b[1])
                assert min(overlap) <= 1e-6, f"seed {sc.seed}: {a} overlaps {b}"


@pytest.mark.parametrize("kind", ["box", "cylinder", "sphere"])
def test_meshes_wind_counter_clockwise_outwards(kind):
    pos, nrm = part_mesh(Part(kind, (0, 0, 0), (1, 2, 1), 0))
    tri = pos.reshape(-1, 3, 3)
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    keep = np.linalg.norm(face_n, axis=1) > 1e-9  # degenerate pole triangles of the sphere
    assert ((face_n * nrm.reshape(-1, 3, 3).mean(1)).sum(1)[keep] > 0).all()


def test_dataset_make_is_split_by_room_and_resumable(tmp_path):
    from x2video.cli import main
    from x2video.io import load_shot

    out = tmp_path / "ds"
    args = ["dataset", "make", "--rooms", "3", "--frames", "2", "--size", "48x32", "--seed", "5", "--out", str(out), "--test-every", "3"]
    assert main(args) == 0
    shots = sorted(p.parent.relative_to(out).as_posix() for p in out.glob("*/*/shot.json"))
    assert shots == ["test/room_00002", "train/room_00000", "train/room_00001"]
    first = (out / "train/room_00000/rgb/000000.exr").stat().st_mtime_ns
    assert main(args) == 0  # finished rooms are skipped
    assert (out / "train/room_00000/rgb/000000.exr").stat().st_mtime_ns == first
    meta = json.loads((out / "dataset.json").read_text())
    assert meta["complete"] and meta["splits"]["test"] == ["test/room_00002"]
    shot = load_shot(out / "train/room_00000")
    assert shot.num_frames == 2 and shot.info.caption and shot.info.object_captions
    assert shot.channel("albedo", 1).shape == (32, 48, 3)
    assert main(["dataset", "make", "--rooms", "1", "--out", str(tmp_path / "x"), "--size", "10"]) == 2  # bad size
    clash = [a if a != "2" else "4" for a in args]  # same folder, other --frames
    assert main(clash) == 2


def test_dataset_demo_writes_a_deterministic_shot(tmp_path, monkeypatch):
    from x2video.cli import dataset, main
    from x2video.io import load_shot

    monkeypatch.setitem(dataset.DEMO, "frames", 3)
    monkeypatch.setitem(dataset.DEMO, "width", 48)
    monkeypatch.setitem(dataset.DEMO, "height", 32)
    shots = []
    for name in ("a", "b"):
        assert main(["dataset", "demo", str(tmp_path / name)]) == 0
        shots.append(load_shot(tmp_path / name))
    a, b = shots
    assert a.num_frames == 3 and a.info.caption == b.info.caption
    for t in range(3):
        for ch in ("rgb", "albedo", "irradiance", "ids"):
            np.testing.assert_array_equal(a.channel(ch, t), b.channel(ch, t))
