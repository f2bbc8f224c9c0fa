"""Issue 31 in the editor: the formula's preview on screen at once and replaced by the render's frames, the
Quality selector, tier-1 (per-frame) renders in the render state, timeline and charts, and a window that
opens without importing torch. Tiny shot, the untrained tiny model or a fake one with a tier-1 net."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from app_helpers import make_shot_dir  # noqa: E402
from PySide6.QtCore import Qt  # noqa: E402
from PySide6.QtWidgets import QMessageBox  # noqa: E402

from x2video.render.events import FramesReady, RenderStarted  # noqa: E402
from x2video_app._qt.main_window import MainWindow  # noqa: E402
from x2video_app._qt.render_panel import NO_RESIDUAL  # noqa: E402
from x2video_app.state.preview import PreviewReady, preview_order  # noqa: E402

TIMEOUT_MS = 240_000


@pytest.fixture(scope="module")
def tiny_model():
    import torch

    torch.set_num_threads(1)
    from x2video.model.pipeline import X2VideoModel

    return X2VideoModel.untrained("tiny")


def with_net():
    """A fake model with a small tier-1 net (as tests/test_tiers.py): quality auto runs tier 1."""
    import torch
    from sampling_fake import FakeModel

    from x2video.model import residual as R

    m = FakeModel()
    torch.manual_seed(0)
    m.residual_net = R.ResidualNet(R.ResidualConfig(widths=(8, 16))).eval()
    return m


@pytest.fixture(scope="module")
def shot_dir(tmp_path_factory):
    return make_shot_dir(tmp_path_factory.mktemp("pshots"), frames=5, h=32, w=48)


def open_window(qtbot, tmp_path, monkeypatch, shot_dir, model) -> MainWindow:
    """The editor on the 5-frame shot with `model` built (as the start-up preload leaves it)."""
    from x2video.render.renderer import Renderer

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("X2VIDEO_WEIGHTS", str(tmp_path / "no-weights"))
    w = MainWindow(bench_dir=tmp_path / "bench", autosave_ms=0)
    w.ask = lambda title, text, buttons, default: QMessageBox.StandardButton.Discard
    w.render_ctl.renderer_factory = lambda choice: Renderer(model)
    qtbot.addWidget(w)
    w.show()
    assert w.project.open_path(shot_dir), w.errors_shown
    w.render_panel.window.setValue(3)
    w.render_panel.base_check.setChecked(False)  # the tiers' renders (over the shot's rgb a render without edits returns it)
    w.act_untrained.setChecked(True)  # a model choice; builds it in the background
    assert w.render_ctl.wait(TIMEOUT_MS) and w.render_ctl.renderer is not None
    return w


@pytest.fixture
def close_after():
    wins = []
    yield wins.append
    for w in wins:
        w.render_ctl.cancel()
        w.render_ctl.wait(TIMEOUT_MS)


def test_formula_preview_shows_at_once_and_network_frames_replace_it(qtbot, tmp_path, monkeypatch, shot_dir, tiny_model, close_after):
    from x2video.conditioning.edited import apply_edits
    from x2video.formula import formula_frame
    from x2video_app.state.display import channel_to_u8

    win = open_window(qtbot, tmp_path, monkeypatch, shot_dir, tiny_model)
    close_after(win)
    win.doc.set_frame(3)
    win.edits.set_param("exposure", 0.5, True)  # the preview shows the edited channels
    events = []
    win.render_ctl.sigEvent.connect(lambda ev: events.append(type(ev).__name__))
    qtbot.mouseClick(win.render_panel.render_button, Qt.MouseButton.LeftButton)
    st = win.doc.render
    # before any worker reported: the frame on screen is the formula's, painted, on the GUI thread
    assert st.arrivals[0] == (3, 0, "preview") and events[0] == "PreviewReady" and win.first_frame_shown_s is not None
    want = formula_frame(apply_edits(win.doc.shot, win.doc.edits, 3))
    np.testing.assert_allclose(st.preview[3].astype(np.float32), want, rtol=2e-3, atol=1e-3)
    assert np.array_equal(win.doc.display_image(), channel_to_u8("rgb", st.preview[3].astype(np.float32), (32, 48)))
    assert "formula preview" in win.info_label.text() and 3 in win.timeline.bar.preview
    assert win.render_ctl.wait(TIMEOUT_MS)
    assert st.status == "finished", (st.status, st.error)
    first_network = next(i for i, a in enumerate(st.arrivals) if a[2] != "preview")
    assert all(a[2] == "preview" for a in st.arrivals[:first_network])
    for t in range(5):  # a frame's preview, if it came at all, came before the render's frame, never after
        seen = [(i, a[2]) for i, a in enumerate(st.arrivals) if a[0] == t]
        rendered = [i for i, kind in seen if kind != "preview"]
        assert rendered and all(i < rendered[0] for i, kind in seen if kind == "preview"), (t, seen)
    assert set(st.frames) == set(range(5)) and not st.preview and not win.timeline.bar.preview
    assert win.first_keyframe_shown_s is not None and win.first_keyframe_shown_s >= win.first_frame_shown_s
    assert events.index("FramesReady") > 0 and "Tier: diffusion" in win.render_panel.status_label.text()


def test_preview_order_and_cancel_keeps_only_rendered_frames(qtbot, tmp_path, monkeypatch, shot_dir, tiny_model, close_after):
    assert preview_order(9, first=4) == [4, 0, 8, 2, 6, 1, 3, 5, 7]
    assert preview_order(5, first=0, skip=[0]) == [4, 2, 1, 3]
    win = open_window(qtbot, tmp_path, monkeypatch, shot_dir, tiny_model)
    close_after(win)
    assert win.start_render()
    win.render_ctl.cancel()  # before the render's first frame
    assert win.render_ctl.wait(TIMEOUT_MS) and win.render_ctl.preview_worker is None
    st = win.doc.render
    assert st.status == "cancelled" and not st.frames and 0 in st.preview  # export and references see no preview
    assert win.render_panel.render_button.isEnabled()


def test_quality_selector_reaches_render_settings(qtbot, tmp_path, monkeypatch, shot_dir, tiny_model, close_after):
    win = open_window(qtbot, tmp_path, monkeypatch, shot_dir, tiny_model)
    close_after(win)
    box = win.render_panel.quality
    residual = box.model().item(box.findData("residual"))
    assert not residual.isEnabled() and box.itemData(box.findData("residual"), Qt.ItemDataRole.ToolTipRole) == NO_RESIDUAL
    assert win.render_ctl.settings(**win.render_panel.values()).quality == "auto"
    box.setCurrentIndex(box.findData("formula"))
    assert win.render_ctl.settings(**win.render_panel.values()).quality == "formula"
    started = []
    win.render_ctl.sigEvent.connect(lambda ev: started.append(ev) if isinstance(ev, RenderStarted) else None)
    assert win.start_render() and win.render_ctl.wait(TIMEOUT_MS)
    st = win.doc.render
    assert started[0].tier == "formula" and st.status == "finished" and set(st.frames) == set(range(5))
    assert not any(a[2] == "preview" for a in st.arrivals)  # the render is the formula: nothing to preview
    assert set(st.levels.values()) == {0} and not st.keyframes and st.level_progress() == [(0, 5, 5)]
    assert "Tier: formula (forced by the user)" in win.render_panel.status_label.text()


def test_tier1_render_completes_and_the_timeline_shows_it(qtbot, tmp_path, monkeypatch, shot_dir, close_after):
    win = open_window(qtbot, tmp_path, monkeypatch, shot_dir, with_net())
    close_after(win)
    box = win.render_panel.quality
    assert box.model().item(box.findData("residual")).isEnabled()  # the built model has the tier-1 net
    ready = []
    win.render_ctl.sigEvent.connect(lambda ev: ready.append(ev) if isinstance(ev, (FramesReady, RenderStarted)) else None)
    shown = []
    win.statusBar().messageChanged.connect(shown.append)
    assert win.start_render() and win.render_ctl.wait(TIMEOUT_MS)
    st = win.doc.render
    assert st.status == "finished", (st.status, st.error)
    started, frames = ready[0], [e for e in ready[1:] if isinstance(e, FramesReady)]
    assert started.tier == "residual" and started.num_windows == 0 and started.levels == [0]
    assert [len(e.frames) for e in frames] == [1, 4] and all(e.mode == "residual" for e in frames)  # the first frame alone
    assert set(st.frames) == set(range(5)) and not st.preview
    assert win.timeline.bar.levels == {t: 0 for t in range(5)} and not win.timeline.bar.keyframes
    assert st.level_progress() == [(0, 5, 5)] and st.eta_seconds() is None
    assert len(win.charts.windows) == 2 and {lv for _, lv, _ in win.charts.windows} == {0}
    assert "residual frames: 5/5 frames" in win.render_panel._bars[0].format()
    assert any("residual tier: every channel present" in m for m in shown)
    assert "Tier: residual" in win.render_panel.status_label.text()


def test_the_window_opens_without_importing_torch(tmp_path):
    """Start-up: the model (torch, diffusers) loads in the background, not before the window shows (where
    the window can tell there is no GPU without torch; else the Device list needs it)."""
    import os

    from x2video_app.state.model_source import cuda_possible

    if cuda_possible():
        pytest.skip("a CUDA build of torch with a GPU driver: the Device list imports torch to ask")
    code = ("import sys\nfrom PySide6.QtWidgets import QApplication\napp = QApplication([])\n"
            "from x2video_app._qt.main_window import MainWindow\nw = MainWindow(preload=False, autosave_ms=0)\n"
            "assert 'torch' not in sys.modules, 'torch imported at start-up'\n")
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "XDG_CACHE_HOME": str(tmp_path), "X2VIDEO_WEIGHTS": str(tmp_path / "none")}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr[-2000:]


def test_render_state_preview_never_overwrites_a_rendered_frame():
    from x2video_app.state.render_state import RenderState

    st = RenderState()
    st.begin(steps_per_window=1)
    a, b = np.zeros((2, 2, 3), np.float32), np.ones((2, 2, 3), np.float32)
    st.apply(PreviewReady(frames={0: a, 1: a}, seconds=0.0))
    st.apply(FramesReady(window=0, frames={1: b}, level=1, mode="key", seconds=0.1))
    st.apply(PreviewReady(frames={1: a, 2: a}, seconds=0.0))  # late: frame 1 is rendered already
    assert set(st.frames) == {1} and set(st.preview) == {0, 2} and float(st.image(1).max()) == 1.0
    assert st.arrivals == [(0, 0, "preview"), (1, 0, "preview"), (1, 1, "key"), (2, 0, "preview")]
    assert st.first_frame_at is not None and st.first_keyframe_at >= st.first_frame_at
