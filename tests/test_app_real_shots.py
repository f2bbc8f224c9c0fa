"""Editor side of issue 29 (real shots): the rendered reference sits where it was rendered, the device
setting, mask propagation in a worker, and exports in the input's units."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from app_helpers import make_shot_dir  # noqa: E402
from PySide6.QtWidgets import QMessageBox  # noqa: E402

from x2video.render.events import FramesReady, RenderStarted  # noqa: E402
from x2video_app._qt.main_window import MainWindow  # noqa: E402


@pytest.fixture(scope="module")
def shot_dir(tmp_path_factory):
    return make_shot_dir(tmp_path_factory.mktemp("shots29"), frames=9, h=32, w=48)


@pytest.fixture
def win(qtbot, shot_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("X2VIDEO_WEIGHTS", str(tmp_path / "no-weights"))
    w = MainWindow(bench_dir=tmp_path / "bench", autosave_ms=0)
    w.ask = lambda title, text, buttons, default: QMessageBox.StandardButton.Discard
    qtbot.addWidget(w)
    w.show()
    assert w.project.open_path(shot_dir), w.errors_shown
    yield w
    w.render_ctl.wait(60_000)


def _fake_render(win, frames: dict[int, np.ndarray]) -> None:
    """Deliver rendered frames to the document as a render would (no model needed)."""
    win.doc.render.begin(1, {1: 1})
    win.doc.render.apply(RenderStarted(num_frames=len(frames), num_windows=1, levels=[1]))
    win.doc.render.apply(FramesReady(window=0, frames=frames, level=1, mode="key", seconds=0.0))


def test_rendered_frame_as_reference_sits_at_that_frame(win):
    from x2video.conditioning.edited import resolve_reference

    rng = np.random.default_rng(1)
    frames = {t: rng.uniform(0, 1, (32, 48, 3)).astype(np.float32) for t in range(9)}
    _fake_render(win, frames)
    win.doc.set_frame(6)
    assert win.edits.use_rendered_reference()
    pos, img = resolve_reference(win.doc.shot, win.doc.edits, None)
    assert pos == 6, "the reference must sit at the frame the person picked, not frame 0"
    np.testing.assert_allclose(img, frames[6], atol=2e-3, rtol=2e-3)
    assert "frame 6" in win.doc.edits.reference.describe()
    # it survives the project file
    from x2video.edits import Edits

    back = Edits.from_dict(win.doc.edits.to_dict())
    assert back.reference.position == 6
    win.act_undo.trigger()
    assert win.doc.edits.reference is None


def _paint_box(win):
    win.edits.add_mask()
    m = np.zeros((32, 48), np.float32)
    m[8:20, 6:20] = 1
    win.doc.set_mask_frame(0, 0, m)
    win.doc.set_frame(0)


def test_mask_propagation_runs_in_a_worker(win, qtbot):
    _paint_box(win)
    steps = win.undo.count()
    worker = win.edits.propagate(0)
    assert worker is not None and win.edits.propagate_worker is worker
    assert win.doc.edits.masks["mask 1"].painted_frames() == [0]  # the call returned before the work was done
    qtbot.waitUntil(lambda: win.edits.propagate_worker is None, timeout=30_000)
    assert win.doc.edits.masks["mask 1"].painted_frames() == list(range(9))
    assert win.edits.propagate_progress == (8, 8)  # progress reached the GUI thread
    assert win.undo.count() == steps + 1
    win.act_undo.trigger()
    assert win.doc.edits.masks["mask 1"].painted_frames() == [0]


def test_mask_propagation_can_be_cancelled_and_the_window_stays_live(win, qtbot, monkeypatch):
    import threading
    import time

    from PySide6.QtCore import QTimer
    from PySide6.QtWidgets import QProgressDialog

    from x2video_app._qt import edit_actions

    started = threading.Event()

    def slow(shot, mask, t0, *, on_progress, should_stop):  # a long shot: 200 frames of flow
        started.set()
        for k in range(200):
            if should_stop():
                return {}
            on_progress(k + 1, 200)
            time.sleep(0.01)
        return {t0: mask}

    monkeypatch.setattr(edit_actions, "propagate_mask", slow)
    _paint_box(win)
    steps = win.undo.count()
    ticks = []
    timer = QTimer()
    timer.timeout.connect(lambda: ticks.append(time.perf_counter()))
    timer.start(10)
    win.edits.propagate(0)
    qtbot.waitUntil(lambda: win.edits.propagate_progress is not None and win.edits.propagate_progress[0] >= 10, timeout=10_000)
    assert len(ticks) >= 3, "the GUI thread kept running timers while the mask propagated"
    dlg = [d for d in win.findChildren(QProgressDialog) if d.windowTitle() == "Propagate mask"][-1]
    from PySide6.QtWidgets import QPushButton

    dlg.findChild(QPushButton).click()  # the dialog's Cancel button
    qtbot.waitUntil(lambda: win.edits.propagate_worker is None, timeout=10_000)
    timer.stop()
    assert win.edits.propagate_progress[0] < 200
    assert win.doc.edits.masks["mask 1"].painted_frames() == [0] and win.undo.count() == steps  # nothing changed
    assert "cancelled" in win.statusBar().currentMessage()


def test_device_setting_defaults_to_auto_and_shows_in_the_status_bar(qtbot, shot_dir, tmp_path, monkeypatch):
    from x2video_app._qt import main_window
    from x2video_app.state import model_source

    monkeypatch.setenv("X2VIDEO_WEIGHTS", str(tmp_path / "no-weights"))
    for cuda in (False, True):
        monkeypatch.setattr(model_source, "cuda_available", lambda c=cuda: c)
        monkeypatch.setattr(main_window, "cuda_available", lambda c=cuda: c)
        w = MainWindow(bench_dir=tmp_path / "bench", autosave_ms=0)
        qtbot.addWidget(w)
        built: list[str] = []
        w.render_ctl.renderer_factory = lambda choice, b=built: b.append(choice.device)  # no model build here
        p = w.render_panel
        assert p.device.currentData() == "auto"
        assert [p.device.itemData(i) for i in range(p.device.count())] == (["auto", "cpu", "cuda"] if cuda else ["auto", "cpu"])
        w.act_untrained.setChecked(True)
        want = "cuda" if cuda else "cpu"
        assert w.render_ctl.choice.device == want and w.device_status.text() == f"Device: {want}"
        if cuda:  # the person picks the CPU: a new model choice (and Renderer) on the CPU
            p.device.setCurrentIndex(p.device.findData("cpu"))
            assert w.render_ctl.choice.device == "cpu" and w.device_status.text() == "Device: cpu"
        assert w.render_ctl.wait(10_000)  # the background (fake) model builds
        w.close()
        assert set(built) <= {"cpu", "cuda"} and (cuda or built == ["cpu"])  # the model is built for the chosen device


def test_model_is_built_on_the_chosen_device():
    from x2video_app.state.model_source import ModelChoice, load_model

    m = load_model(ModelChoice("untrained", device="cpu"))
    assert str(m.device) == "cpu"


def test_editor_export_writes_the_inputs_units(tmp_path):
    """The editor's EXR/MP4 export goes through the same OutputUnits as the CLI."""
    import av

    from x2video.channels import tonemap
    from x2video.io.image import read_image
    from x2video.io.units import OutputUnits
    from x2video.shot import ArrayShot
    from x2video_app.state.exporter import export_exr, export_mp4

    T, h, w = 2, 8, 12
    shot = ArrayShot({"albedo": np.full((T, h, w, 3), 0.5, np.float32), "irradiance": np.full((T, h, w, 3), 0.4, np.float32)},
                     irradiance_scale=0.25)
    frames = {t: np.full((h, w, 3), 0.2, np.float32) for t in range(T)}  # the model's exposure
    list(export_exr(frames, tmp_path / "exr", shot, edits=None))
    np.testing.assert_allclose(read_image(tmp_path / "exr" / "000001.exr").channel("R"), 0.8, rtol=1e-3)  # 0.2 / 0.25
    list(export_mp4(frames, tmp_path / "a.mp4", 10.0, OutputUnits.for_shot(shot, -2.0)))
    with av.open(str(tmp_path / "a.mp4")) as c:
        got = next(c.decode(video=0)).to_ndarray(format="rgb24")
    assert abs(float(got.mean()) - float(tonemap(np.float32(0.8 * 2 ** -2)) * 255)) < 3
