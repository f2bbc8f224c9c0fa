"""The demo shot (`x2video.demo`): the path-traced room where bpy is installed (here at 2 frames, 48x32, 4 samples), with
its Cycles ground truth for the editor's Compare and PSNR; the rasterized room, and one log line saying why, where
Cycles is unavailable or its render fails."""
import json
import logging
import sys

import numpy as np
import pytest

import x2video.cycles.demo as cdemo
import x2video.demo as demo
import x2video.procedural.demo as pdemo
from x2video.cycles.demo import CyclesDemo, CyclesDemoUnavailable
from x2video.demo import ensure_demo
from x2video.io import load_shot

TINY = CyclesDemo(frames=2, width=48, height=32, samples=4, threads=1)


@pytest.fixture
def small_raster(monkeypatch):
    """The rasterized demo at 2 frames and 64x48 (its folder name follows)."""
    for k, v in {"frames": 2, "width": 64, "height": 48}.items():
        monkeypatch.setitem(pdemo.DEMO, k, v)


@pytest.mark.slow
@pytest.mark.skipif(cdemo.bpy_missing() is not None, reason="needs bpy (x2video-studio[cycles])")
def test_the_demo_is_the_path_traced_room_with_its_ground_truth(tmp_path):
    seen = []
    folder = ensure_demo(tmp_path, "auto", spec=TINY, progress=lambda done, total, s: seen.append((done, total)))
    assert folder == tmp_path / TINY.folder_name
    assert seen == [(0, 2), (1, 2), (2, 2)], seen  # set-up, then each frame
    shot = load_shot(folder)
    assert shot.num_frames == 2 and shot.size == (32, 48)
    assert {"albedo", "normal", "roughness", "metallic", "irradiance", "rgb"} <= set(shot.channels)
    rgb = shot.channel("rgb", 1)
    assert rgb.shape == (32, 48, 3) and np.isfinite(rgb).all() and rgb.mean() > 0.01
    extra = shot.info.extra
    assert extra["renderer"].startswith("Cycles") and extra["room_seed"] == TINY.seed
    pt = extra["path_traced"]  # the room the issue asks for: a window, a glossy floor and metal
    assert pt["windows"] >= 1 and pt["glossy_floor"] is not None and pt["metal"]
    rec = json.loads((folder / "x2video-demo.json").read_text())
    assert rec["frames_rendered"] == 2 and rec["spec"]["samples"] == 4 and rec["cpu_seconds"] > 0
    assert "path-traced in" in cdemo.describe(folder)
    # made once: the next start opens the cache without Blender
    again = []
    assert ensure_demo(tmp_path, "auto", spec=TINY, progress=lambda *a: again.append(a)) == folder and not again


def test_without_bpy_the_demo_is_the_rasterized_room_and_says_why(tmp_path, monkeypatch, caplog, small_raster):
    monkeypatch.setitem(sys.modules, "bpy", None)  # `import bpy` fails, find_spec finds nothing
    with caplog.at_level(logging.INFO, logger="x2video.demo"):
        folder = ensure_demo(tmp_path, "auto", spec=TINY)
    assert folder.name == "seed7-2f-64x48" and not (tmp_path / TINY.folder_name).exists()
    shot = load_shot(folder)
    assert shot.num_frames == 2 and shot.has("albedo")
    lines = [r.getMessage() for r in caplog.records if r.name == "x2video.demo"]
    assert len(lines) == 1 and "rasterized" in lines[0] and "bpy" in lines[0] and "not installed" in lines[0], lines
    with pytest.raises(CyclesDemoUnavailable, match="bpy"):  # asked for Cycles alone: an error, not the other room
        ensure_demo(tmp_path, "cycles", spec=TINY)


def test_a_failed_render_falls_back_and_is_not_retried_every_start(tmp_path, monkeypatch, caplog, small_raster):
    monkeypatch.setattr(cdemo, "bpy_missing", lambda: None)
    fail = "import sys; print('Error: no GPU today', file=sys.stderr); sys.exit(3)"
    monkeypatch.setattr(cdemo, "_command", lambda folder, spec: [sys.executable, "-c", fail])
    with caplog.at_level(logging.WARNING, logger="x2video.demo"):
        folder = ensure_demo(tmp_path, "auto", spec=TINY)
    assert folder.name == "seed7-2f-64x48"
    assert "exit 3: Error: no GPU today" in caplog.records[-1].getMessage()
    failed = tmp_path / (TINY.folder_name + ".failed")
    assert failed.is_file()
    monkeypatch.setattr(cdemo, "_command", lambda folder, spec: pytest.fail("rendered again"))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="x2video.demo"):
        assert ensure_demo(tmp_path, "auto", spec=TINY) == folder
    assert "earlier Cycles render of it failed" in caplog.records[-1].getMessage() and str(failed) in caplog.records[-1].getMessage()


def test_the_demo_renderer_comes_from_the_environment(tmp_path, monkeypatch, small_raster):
    monkeypatch.setattr(demo, "ensure_cycles_demo", lambda *a: pytest.fail("asked Cycles"))
    monkeypatch.setenv("X2VIDEO_DEMO_RENDERER", "raster")
    assert ensure_demo(tmp_path).name == "seed7-2f-64x48"
    monkeypatch.setenv("X2VIDEO_DEMO_RENDERER", "blender")
    with pytest.raises(ValueError, match="X2VIDEO_DEMO_RENDERER"):
        ensure_demo(tmp_path)


def test_the_editor_hears_each_frame_and_why_the_demo_is_rasterized(tmp_path, monkeypatch):
    """x2video_app.state.demo reads the child's progress lines, its warnings and the folder it made."""
    import x2video_app.state.demo as app_demo

    (tmp_path / "shot").mkdir()
    (tmp_path / "shot" / "shot.json").write_text("{}")
    child = ("import sys, time\n"
             "for d in range(3): print(f'progress {d} 2 1.5', flush=True); time.sleep(0.05)\n"
             "print('WARNING x2video.demo: demo: the rasterized room, not the path-traced one: no bpy', file=sys.stderr)\n"
             f"print('DEMO={tmp_path / 'shot'}')\n")
    monkeypatch.setattr(app_demo, "_command", lambda: [sys.executable, "-c", child])
    seen, notes, polls = [], [], []
    got = app_demo.ensure_demo(poll=lambda: polls.append(1), on_progress=lambda *a: seen.append(a), on_note=notes.append)
    assert got == tmp_path / "shot" and seen == [(0, 2, 1.5), (1, 2, 1.5), (2, 2, 1.5)] and polls
    assert notes == ["demo: the rasterized room, not the path-traced one: no bpy"]
    monkeypatch.setattr(app_demo, "_command", lambda: [sys.executable, "-c", "import sys; sys.exit('Blender crashed')"])
    with pytest.raises(RuntimeError, match="Blender crashed"):
        app_demo.ensure_demo()


def test_render_demo_shows_a_bar_and_says_what_it_made(tmp_path, monkeypatch, caplog, capsys):
    from x2video.cli.render import _demo

    folder = tmp_path / TINY.folder_name
    folder.mkdir()
    (folder / "x2video-demo.json").write_text(json.dumps({"spec": {"frames": 2, "width": 48, "height": 32, "samples": 4},
                                                          "seconds": 9.5, "cpu_seconds": 17.0}))

    def fake(cache, progress=None):
        for d in range(3):
            progress(d, 2, 1.0)
        return folder

    monkeypatch.setattr(demo, "ensure_demo", fake)
    with caplog.at_level(logging.INFO, logger="x2video.cli.render"):
        assert _demo(tmp_path) == folder
    text = " ".join(r.getMessage() for r in caplog.records)
    assert "path-tracing the demo room" in text and "2 frames at 48x32, 4 spp, path-traced in 9.5 s (17.0 CPU s)" in text
    assert "demo (Cycles)" in capsys.readouterr().err  # the bar
