"""Editor side of issue 29 (real shots): the rendered reference sits where it was rendered, the device
setting, mask propagation in a worker, and exports in the input's units."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from PySide6.QtWidgets import QMessageBox  # noqa: E402

from app_helpers import make_shot_dir  # noqa: E402
from x2video.sampling.events import FramesReady, RenderStarted  # noqa: E402
from x2video_app import edit_ops  # noqa: E402
from x2video_app.main_window import MainWindow  # noqa: E402


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
    from x2video.edits import resolve_reference

    rng = np.random.default_rng(1)
    frames = {t: rng.uniform(0, 1, (32, 48, 3)).astype(np.float32) for t in range(9)}
    _fake_render(win, frames)
    win.doc.set_frame(6)
    assert win.edits.use_rendered_reference()
    pos, img = resolve_reference(win.doc.shot, win.doc.edits, None)
    assert pos == 6, "the reference must sit at the frame the person picked, not frame 0"
    np.testing.assert_allclose(img, frames[6], atol=2e-3, rtol=2e-3)
    assert "frame 6" in edit_ops.reference_text(win.doc.edits)
    # it survives the project file
    from x2video.edits import Edits

    back = Edits.from_dict(win.doc.edits.to_dict())
    assert back.reference.position == 6
    win.act_undo.trigger()
    assert win.doc.edits.reference is None
