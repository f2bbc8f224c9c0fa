"""The editor on a keyframe shot (rgb on frames 0 and 4 of 5): the timeline marks the keyframes and its strip says
which frames are path-traced, filled, or edited by which tier; the live preview shows an edit as a difference over
the shot's own frames; the EXR export gives the input's rgb back bit for bit outside the edit. No model: tier 0."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from app_helpers import make_shot_dir  # noqa: E402
from PySide6.QtCore import Qt  # noqa: E402
from PySide6.QtWidgets import QMessageBox  # noqa: E402

from x2video.base.difference import SPILL_MARGIN  # noqa: E402
from x2video_app._qt.main_window import MainWindow  # noqa: E402

TIMEOUT_MS = 120_000
BOX = (slice(8, 20), slice(10, 30))  # the edited region, rows x columns of the 32 x 48 frames


@pytest.fixture(scope="module")
def shot_dir(tmp_path_factory):
    folder = make_shot_dir(tmp_path_factory.mktemp("kshots"), frames=5, h=32, w=48)
    for t in (1, 2, 3):  # a keyframe shot: Cycles rendered frames 0 and 4, the rest are G-buffers only
        (folder / "rgb" / f"{t:06d}.exr").unlink()
    return folder


@pytest.fixture
def win(qtbot, tmp_path, monkeypatch, shot_dir):
    from x2video.render.renderer import Renderer

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("X2VIDEO_WEIGHTS", str(tmp_path / "no-weights"))
    w = MainWindow(bench_dir=tmp_path / "bench", autosave_ms=0)
    w.ask = lambda title, text, buttons, default: QMessageBox.StandardButton.Discard
    w.render_ctl.renderer_factory = lambda choice: Renderer(None)  # tier 0 needs no model
    qtbot.addWidget(w)
    w.show()
    assert w.project.open_path(shot_dir), w.errors_shown
    w.act_untrained.setChecked(True)  # a model choice, so Render starts; the factory builds no model
    assert w.render_ctl.wait(TIMEOUT_MS)
    w.render_panel.quality.setCurrentIndex(w.render_panel.quality.findData("formula"))
    w.doc.set_view("rendered")
    yield w
    w.live.shutdown()
    w.render_ctl.cancel()
    w.render_ctl.wait(TIMEOUT_MS)


def albedo_edit(win, qtbot) -> np.ndarray:
    """A mask over BOX on every frame, recoloured; returns where the edit may reach (the box and its spill margin)."""
    win.edits.add_mask()
    m = np.zeros(win.doc.size, np.float32)
    m[BOX] = 1
    for t in range(win.doc.num_frames):
        win.doc.set_mask_frame(0, t, m)
    win.edits.set_param("albedo_colour", (0.9, 0.1, 0.1), True)
    qtbot.waitUntil(lambda: win.live.idle, timeout=TIMEOUT_MS)
    reach = np.zeros(win.doc.size, bool)
    reach[BOX[0].start - SPILL_MARGIN - 1:BOX[0].stop + SPILL_MARGIN + 1, BOX[1].start - SPILL_MARGIN - 1:BOX[1].stop + SPILL_MARGIN + 1] = True
    return reach


def render(win, qtbot) -> None:
    qtbot.mouseClick(win.render_panel.render_button, Qt.MouseButton.LeftButton)
    assert win.render_ctl.wait(TIMEOUT_MS)
    assert win.doc.render.status == "finished", (win.doc.render.error, win.errors_shown)


def test_timeline_marks_the_keyframes_and_the_strip_says_where_each_frame_comes_from(qtbot, win):
    bar = win.timeline.bar
    assert bar.marks == {0, 4} and bar.kinds == {0: "path-traced", 4: "path-traced"}  # before any render
    win.doc.set_frame(2)
    assert "not rendered yet" in win.info_label.text()
    render(win, qtbot)  # no edit: the keyframes as they are, the frames between filled
    assert bar.kinds == {0: "path-traced", 1: "filled", 2: "filled", 3: "filled", 4: "path-traced"} and bar.marks == {0, 4}
    arrived = [t for t, _, mode in win.doc.render.arrivals if mode != "preview"]
    assert arrived == [0, 4, 1, 3, 2]  # the keyframes, then the frames between nearest a keyframe first
    assert "filled from its nearest keyframes" in win.info_label.text()
    albedo_edit(win, qtbot)
    render(win, qtbot)
    assert bar.kinds == {t: "formula" for t in range(5)} and win.doc.render.modes == {t: "formula" for t in range(5)}
    win.doc.set_frame(0)
    assert "path-traced + tier 0's difference (formula)" in win.info_label.text()
    bar.grab()  # paints the marks and the strip


def test_the_live_preview_shows_an_edit_over_the_shots_path_traced_frame(qtbot, win):
    win.doc.set_frame(0)
    reach = albedo_edit(win, qtbot)
    res = win.live.shown
    assert res is not None and res.t == 0 and res.frame.tier == "formula" and win.doc.live is res
    shot = win.doc.shot
    base = shot.channel("rgb", 0).astype(np.float64) * shot.info.irradiance_scale  # the model's exposure
    np.testing.assert_array_equal(res.image[~reach], base.astype(np.float32)[~reach])  # the base, untouched
    assert np.abs(res.image[BOX] - base[BOX]).max(-1).min() > 1e-3  # the edit, over it


def test_export_writes_the_input_rgb_bit_for_bit_outside_the_edit(qtbot, win, tmp_path):
    from x2video.io.image import read_image

    reach = albedo_edit(win, qtbot)
    render(win, qtbot)
    worker = win.exporting.export("exr", tmp_path / "out")
    qtbot.waitUntil(lambda: win.exporting.export_worker is None, timeout=TIMEOUT_MS)
    assert not win.errors_shown, win.errors_shown
    del worker
    shot = win.doc.shot
    for t in (0, 4):  # the keyframes: the input's own rgb in its own units, outside the edit
        img = read_image(tmp_path / "out" / f"{t:06d}.exr")  # the CLI's layout: R, G, B in the input's units
        out, rgb = np.stack([img.channel(c) for c in "RGB"], -1), shot.channel("rgb", t)
        np.testing.assert_array_equal(out[~reach], rgb[~reach])
        assert np.abs(out[BOX] - rgb[BOX]).max(-1).min() > 1e-3
