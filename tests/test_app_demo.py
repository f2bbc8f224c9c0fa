"""The editor's demo start (issue 43): the Cycles render's progress in the dialog, why the demo is the rasterized room
in the status bar, and the ground truth of a Cycles shot named as such in Compare (the render itself is faked here;
tests/test_demo.py path-traces one)."""
from __future__ import annotations

import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from app_helpers import make_shot_dir  # noqa: E402
from PySide6.QtWidgets import QProgressDialog  # noqa: E402

import x2video_app._qt.project_controller as pc  # noqa: E402
from x2video_app._qt.main_window import MainWindow  # noqa: E402


@pytest.fixture
def win(qtbot, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("X2VIDEO_WEIGHTS", str(tmp_path / "no-weights"))
    w = MainWindow(bench_dir=tmp_path / "bench", autosave_ms=0)
    qtbot.addWidget(w)
    w.show()
    return w


def test_open_demo_shows_the_frames_left_and_why_it_is_rasterized(win, tmp_path, monkeypatch):
    shot = make_shot_dir(tmp_path, frames=3, h=32, w=48)
    labels = []

    def fake(poll=None, on_progress=None, on_note=None):
        for done in range(3):
            on_progress(done, 2, 3.0)
            dlg = win.findChild(QProgressDialog)
            labels.append((dlg.value(), dlg.maximum(), dlg.labelText()))
            poll()
        on_note("demo: the rasterized room, not the path-traced one: bpy is not installed")
        return shot

    monkeypatch.setattr(pc, "ensure_demo", fake)
    assert win.project.open_demo(), win.errors_shown
    assert win.doc.num_frames == 3
    assert "building the room" in labels[0][2] and "minutes" in labels[0][2]
    assert labels[1][:2] == (1, 2) and "frame 1 of 2, about 3 s left" in labels[1][2]
    assert labels[2][:2] == (2, 2) and "frame 2 of 2" in labels[2][2]
    assert "bpy is not installed" in win.statusBar().currentMessage()
    _, what = win.compare.source("ground truth")
    assert what == "ground truth"
    win.doc.shot.info.extra["renderer"] = "Cycles (Blender 4.2.0)"  # as the path-traced demo's shot.json says
    _, what = win.compare.source("ground truth")
    assert what == "ground truth (Cycles)"
