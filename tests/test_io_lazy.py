"""Shots load lazily: nothing is decoded until asked, and the decoded-frame cache is bounded."""
import shutil

import numpy as np

import x2video.io.folder as folder_mod
import x2video.io.multilayer as ml_mod
from x2video.io import ShotWriter, load_shot
from x2video.io.writers import write_multilayer
from x2video.shot import ShotInfo

T, H, W = 1000, 4, 6


def _many_frames(root):
    """A 1,000-frame shot made by copying one written frame (fast), frame t tagged in pixel (0, 0)."""
    info = ShotInfo(num_frames=1, height=H, width=W, channels=())
    with ShotWriter(root / "seed", info) as w:
        w.write_frame(0, {"albedo": np.full((H, W, 3), 0.25, np.float32), "roughness": np.full((H, W, 1), 0.5, np.float32)})
    for c in ("albedo", "roughness"):
        (root / "shot" / c).mkdir(parents=True)
        for t in range(T):
            shutil.copyfile(root / "seed" / c / "000000.exr", root / "shot" / c / f"{t:06d}.exr")
    return root / "shot"


def test_thousand_frames_lazy_and_bounded(tmp_path, monkeypatch):
    path = _many_frames(tmp_path)
    calls = []
    real = folder_mod.read_image
    monkeypatch.setattr(folder_mod, "read_image", lambda p: calls.append(p) or real(p))
    shot = load_shot(path, cache_size=8)
    assert shot.num_frames == T and calls == []  # loading decoded no pixels
    for t in range(0, T, 50):
        shot.frame(t)
    assert len(calls) == 2 * 20
    assert len(shot._cache) <= 8  # bounded: never more than 8 decoded arrays held
    n = len(calls)
    shot.channel("albedo", 950)  # recent: served from the cache
    assert len(calls) == n
    shot.channel("albedo", 0)  # evicted long ago: read again
    assert len(calls) == n + 1


def test_multilayer_lazy(tmp_path, monkeypatch):
    from x2video.shot import ArrayShot

    src = ArrayShot({"albedo": np.random.default_rng(0).random((12, H, W, 3))})
    write_multilayer(src, tmp_path / "ml")
    calls = []
    real = ml_mod.read_image
    monkeypatch.setattr(ml_mod, "read_image", lambda p, **kw: calls.append(p) or real(p, **kw))
    shot = load_shot(tmp_path / "ml", cache_size=3)
    assert calls == []
    for t in range(12):
        shot.channel("albedo", t)
    assert len(calls) == 12 and len(shot._cache) <= 3
