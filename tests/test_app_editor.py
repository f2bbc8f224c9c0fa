"""The editor driven through its real widgets: open, paint, prompts, parametric edits, undo/redo,
project save/reload, autosave recovery, the unsaved-changes guard, bad files."""
from __future__ import annotations

import copy

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from app_helpers import make_shot_dir  # noqa: E402
from PySide6.QtCore import QPointF, Qt  # noqa: E402
from PySide6.QtWidgets import QMessageBox  # noqa: E402

from x2video_app._qt.main_window import MainWindow  # noqa: E402


@pytest.fixture(scope="module")
def shot_dir(tmp_path_factory):
    return make_shot_dir(tmp_path_factory.mktemp("shots"))


@pytest.fixture
def win(qtbot, shot_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("X2VIDEO_WEIGHTS", str(tmp_path / "no-weights"))
    w = MainWindow(bench_dir=tmp_path / "bench", autosave_ms=0)
    w.answers = []  # queued answers for question dialogs; default: Discard/No
    w.ask = lambda title, text, buttons, default: w.answers.pop(0) if w.answers else QMessageBox.StandardButton.Discard
    qtbot.addWidget(w)
    w.resize(1280, 800)
    w.show()
    assert w.project.open_path(shot_dir), w.errors_shown
    return w


def viewer_pixels(w: MainWindow) -> np.ndarray:
    img = w.viewer.image().convertToFormat(w.viewer.image().Format.Format_RGB888)
    ptr = img.constBits()
    return np.frombuffer(ptr, np.uint8).reshape(img.height(), img.bytesPerLine())[:, : img.width() * 3].reshape(img.height(), img.width(), 3).copy()


def drag(qtbot, w: MainWindow, a: tuple[float, float], b: tuple[float, float]) -> None:
    vp = w.viewer.viewport()
    pa, pb = w.viewer.mapFromScene(QPointF(*a)), w.viewer.mapFromScene(QPointF(*b))
    qtbot.mousePress(vp, Qt.MouseButton.LeftButton, pos=pa)
    for k in range(1, 5):
        qtbot.mouseMove(vp, pa + (pb - pa) * (k / 4))
    qtbot.mouseRelease(vp, Qt.MouseButton.LeftButton, pos=pb)


def test_open_shows_channels_and_switches_views(win, qtbot):
    assert win.doc.num_frames == 9 and win.timeline.frame_box.maximum() == 8
    seen = {}
    for mode in ("albedo", "normal", "ids", "irradiance", "rendered"):
        win.view_box.setCurrentIndex(win.view_box.findData(mode))
        seen[mode] = viewer_pixels(win)
    assert seen["albedo"].shape == (64, 96, 3)
    assert not np.array_equal(seen["albedo"], seen["normal"]) and not np.array_equal(seen["ids"], seen["albedo"])
    win.timeline.frame_box.setValue(4)
    assert win.doc.frame == 4 and win.timeline.bar.current == 4
    assert "demo" not in win.windowTitle() and "shot" in win.windowTitle()


def test_paint_prompt_edit_undo_redo(win, qtbot):
    doc = win.doc
    qtbot.mouseClick(win.mask_panel.add_button, Qt.MouseButton.LeftButton)
    assert list(doc.edits.masks) == ["mask 1"] and doc.selected_mask == 0
    win.mask_panel.tool_buttons["brush"].click()
    win.mask_panel.size.setValue(4)
    drag(qtbot, win, (10, 40), (40, 40))
    m = doc.edits.masks["mask 1"].frames[0]
    assert m[40, 25] == 1.0 and m[10, 25] == 0.0 and m.sum() > 30
    assert win.isWindowModified()

    # local prompt typed into the field
    win.mask_panel.prompt.setFocus()
    win.mask_panel.prompt.setText("a green velvet sofa")
    win.mask_panel.prompt.editingFinished.emit()
    assert doc.edits.local_prompts == {"mask 1": "a green velvet sofa"}

    # albedo hue on the whole frame: the viewer (albedo view) shows the edit before any render
    win.view_box.setCurrentIndex(win.view_box.findData("albedo"))
    before = viewer_pixels(win)
    win.edit_panel.global_box.setChecked(True)
    assert doc.edit_target() is None
    win.edit_panel.hue.setValue(120.0)
    after = viewer_pixels(win)
    assert not np.array_equal(before, after)
    diff = np.abs(after.astype(int) - before.astype(int)).sum(-1)
    assert diff[20, 18] > 100 and diff[45, 60] > 100  # the red and the blue box turned another hue
    # a mask-only edit: roughness set to 0.1 inside mask 1 changes roughness only there
    win.edit_panel.global_box.setChecked(False)
    assert doc.edit_target() == 0
    win.edit_panel.rough_mode.setCurrentIndex(win.edit_panel.rough_mode.findData("set"))
    win.edit_panel.rough.setValue(0.1)
    r = doc.conditioning(0).channels["roughness"][..., 0]
    assert r[40, 25] == pytest.approx(0.1, abs=1e-3) and r[10, 80] == pytest.approx(0.6, abs=1e-3)

    # undo everything, step by step, then redo it all
    edited = copy.deepcopy(doc.edits)
    n = win.undo.count()
    assert n >= 5
    while win.undo.canUndo():
        win.act_undo.trigger()
    assert doc.edits.masks == {} and doc.edits.ops == [] and not win.isWindowModified()
    assert np.array_equal(viewer_pixels(win), before)
    while win.undo.canRedo():
        win.act_redo.trigger()
    assert doc.edits == edited
    assert doc.conditioning(0).channels["roughness"][40, 25, 0] == pytest.approx(0.1, abs=1e-3)
    assert np.array_equal(viewer_pixels(win), after)


def test_fill_by_id_propagate_mask_out_and_drop(win, qtbot):
    doc = win.doc
    win.mask_panel.tool_buttons["fill"].click()
    qtbot.mouseClick(win.viewer.viewport(), Qt.MouseButton.LeftButton, pos=win.viewer.mapFromScene(QPointF(60, 45)))
    assert doc.edits.masks["mask 1"].ids == [2]  # clicked the blue box: the mask holds its id on every frame
    assert doc.mask_layers(8)[0][0][45, 66] == 1.0
    win.mask_panel.mask_out.setChecked(True)
    c = doc.conditioning(3)
    assert c.amr_mask.sum() > 0 and np.all(c.channels["albedo"][c.amr_mask > 0.5] == 0)
    # propagate a painted box along the shot
    qtbot.mouseClick(win.mask_panel.add_button, Qt.MouseButton.LeftButton)
    assert doc.selected_mask == 1
    m = np.zeros((64, 96), np.float32)
    m[8:30, 6:30] = 1  # object 1 on frame 0
    doc.set_mask_frame(1, 0, m)
    win.mask_panel.propagate_button.click()
    qtbot.waitUntil(lambda: win.edits.propagate_worker is None, timeout=30_000)  # runs in a worker
    painted = doc.edits.masks["mask 2"].painted_frames()
    assert painted == list(range(9))
    win.act_undo.trigger()
    assert doc.edits.masks["mask 2"].painted_frames() == [0]
    # drop irradiance through the Scene panel's checkbox
    win.scene_panel.keep["irradiance"].setChecked(False)
    assert doc.edits.dropped == {"irradiance"} and doc.conditioning(0).channels["irradiance"] is None


def test_project_save_reload_equal_and_title(win, qtbot, tmp_path):
    doc = win.doc
    win.edits.add_mask()
    doc.set_mask_frame(0, 2, np.pad(np.ones((10, 10), np.float32), ((5, 49), (5, 81))))
    win.edits.set_local_prompt(0, "a marble statue")
    win.edits.set_global_prompt("a bright gallery")
    win.edits.set_param("exposure", 1.5, True)
    win.doc.set_edit_global(True)
    win.edits.set_param("albedo_tint", (1.0, 0.5, 0.5), True)
    ref = tmp_path / "ref.png"
    from x2video.io.image import write_ldr

    write_ldr(ref, np.full((30, 40, 3), 0.5, np.float32))
    assert win.edits.load_reference(str(ref))
    assert win.isWindowModified() and "*" in win.windowTitle()
    path = tmp_path / "proj.x2v.json"
    assert win.project.save_to(path)
    assert not win.isWindowModified()
    assert win.windowTitle().startswith("proj.x2v.json")

    other = MainWindow(bench_dir=tmp_path, autosave_ms=0)
    qtbot.addWidget(other)
    assert other.project.open_path(path), other.errors_shown
    assert other.doc.edits == doc.edits
    assert other.doc.shot_path == str(win.doc.shot_path) or other.doc.shot.num_frames == win.doc.shot.num_frames
    assert other.doc.reference_image() is not None


def test_autosave_and_recovery(win, qtbot, tmp_path):
    path = tmp_path / "p.x2v.json"
    assert win.project.save_to(path)
    win.edits.set_global_prompt("changed after saving")
    side = win.project.autosave()
    assert side is not None and side.exists() and side != path
    other = MainWindow(bench_dir=tmp_path, autosave_ms=0)
    qtbot.addWidget(other)
    other.ask = lambda *a: QMessageBox.StandardButton.Yes  # "Recover autosaved work?"
    assert other.project.open_path(path)
    assert other.doc.edits.global_prompt == "changed after saving"
    assert other.doc.project_path == path and other.isWindowModified()
    assert other.project.save()
    assert not side.exists()  # saving consumes the side file


def test_quit_asks_when_unsaved(win, qtbot):
    win.edits.set_global_prompt("unsaved")
    win.answers = [QMessageBox.StandardButton.Cancel]
    assert not win.close() and win.isVisible()
    win.answers = [QMessageBox.StandardButton.Discard]
    assert win.close()


def test_bad_files_keep_the_project(win, tmp_path):
    win.edits.set_global_prompt("keep me")
    bad = tmp_path / "broken.x2v.json"
    bad.write_text('{"format": "x2video-project", "version": 99, "shot": "x"}')
    win.answers = [QMessageBox.StandardButton.Discard, QMessageBox.StandardButton.Discard]
    assert not win.project.open_path(bad)
    assert not win.project.open_path(tmp_path / "missing_shot")
    assert len(win.errors_shown) == 2 and "newer" in win.errors_shown[0][1]
    assert win.doc.edits.global_prompt == "keep me" and win.doc.num_frames == 9
    (tmp_path / "bad.png").write_bytes(b"not a png")
    assert not win.edits.load_reference(str(tmp_path / "bad.png"))
    assert "bad.png" in win.errors_shown[-1][1] and win.doc.edits.reference is None


def test_untitled_work_is_autosaved_and_offered_back(win, qtbot, tmp_path, shot_dir):
    win.edits.add_mask()
    win.edits.set_local_prompt(0, "autosaved prompt")
    side = win.project.autosave()
    assert side is not None and side.is_file() and str(tmp_path / "cache") in str(side)
    other = MainWindow(bench_dir=tmp_path, autosave_ms=0)
    qtbot.addWidget(other)
    asked = []
    other.ask = lambda title, *a: asked.append(title) or QMessageBox.StandardButton.Yes
    assert other.project.open_path(shot_dir)
    assert asked == ["Recover autosaved work?"]
    assert other.doc.edits.local_prompts == {"mask 1": "autosaved prompt"} and other.isWindowModified()
    assert other.doc.project_path is None


def test_slider_drag_is_one_undo_step(win):
    count = win.undo.count()
    for v, final in ((10.0, False), (20.0, False), (35.0, True)):
        win.edit_panel.sigParam.emit("hue", v, final)
    assert win.undo.count() == count + 1
    assert win.doc.edits.tuning(None)["hue"] == 35.0
    win.edit_panel.sigParam.emit("hue", 50.0, True)  # a new drag after release is a new step
    assert win.undo.count() == count + 2
    win.act_undo.trigger()
    win.act_undo.trigger()
    assert win.doc.edits.tuning(None)["hue"] == 0.0 and win.doc.edits.ops == []
    assert win.edit_panel.hue.value() == 0.0  # the panel follows the document


def test_render_start_marks_its_setting_on_the_pareto_chart(win, tmp_path):
    import json
    from types import SimpleNamespace

    from sampling_fake import FakeModel

    from x2video.render.settings import RenderSettings
    from x2video_app._qt.charts import load_pareto

    h, w = win.doc.shot.size
    rows = [{"method": m, "label": m, "family": m, "size": [w, h], "seconds_per_frame": 0.5, "psnr": 20.0} for m in ("formula", "lcm-2", "ddim-4")]
    (tmp_path / "pareto.json").write_text(json.dumps({"format": "x2video-pareto", "rows": rows}))
    win.charts.pareto = load_pareto(tmp_path / "pareto.json")
    win.render_settings = RenderSettings(preset="fast")
    win.render_ctl.renderer = SimpleNamespace(model=FakeModel(has_lcm=True))  # the preset resolves as the Renderer does
    assert win.mark_chart("diffusion")["method"] == "lcm-2"
    win.render_ctl.renderer = SimpleNamespace(model=FakeModel(has_lcm=False))
    assert win.mark_chart("diffusion")["method"] == "ddim-4"
    assert win.mark_chart("formula")["method"] == "formula"
    win.render_ctl.renderer = None
