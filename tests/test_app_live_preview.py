"""Issue 43 in the editor: a live preview of the frame on screen while an edit control changes, latest-wins off the GUI
thread, full quality once the edits rest, the sampler's frame after a local prompt, and a whole-shot render only on
Render or with Auto re-render. A 5-frame 32x48 shot and a fake model with a small tier-1 net."""
from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from app_helpers import make_shot_dir  # noqa: E402
from PySide6.QtWidgets import QMessageBox  # noqa: E402

from x2video_app._qt.main_window import MainWindow  # noqa: E402
from x2video_app.state.display import channel_to_u8  # noqa: E402
from x2video_app.tools.tick_probe import TickProbe  # noqa: E402

TIMEOUT_MS = 120_000
#: each live frame takes at least this long in the drag test, so twenty inputs in a second outrun it
SLOW_S = 0.12


def with_net():
    """A fake model with a small tier-1 net: quality auto renders tier 1 where nothing must be generated."""
    import torch
    from sampling_fake import FakeModel

    from x2video.model import residual as R

    m = FakeModel()
    torch.manual_seed(0)
    m.residual_net = R.ResidualNet(R.ResidualConfig(widths=(8, 16))).eval()
    torch.nn.init.normal_(m.residual_net.out.weight, std=0.1)  # not the zero init: the net must change frames
    return m


@pytest.fixture(scope="module")
def shot_dir(tmp_path_factory):
    return make_shot_dir(tmp_path_factory.mktemp("lshots"), frames=5, h=32, w=48)


@pytest.fixture
def win(qtbot, tmp_path, monkeypatch, shot_dir, torch_one_thread):
    """The editor on the 5-frame shot, the fake model built, the rendered view on screen; waits for its workers after."""
    from x2video.render.renderer import Renderer

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("X2VIDEO_WEIGHTS", str(tmp_path / "no-weights"))
    model = with_net()
    w = MainWindow(bench_dir=tmp_path / "bench", autosave_ms=0)
    w.ask = lambda title, text, buttons, default: QMessageBox.StandardButton.Discard
    w.render_ctl.renderer_factory = lambda choice: Renderer(model)
    qtbot.addWidget(w)
    w.show()
    assert w.project.open_path(shot_dir), w.errors_shown
    w.render_panel.window.setValue(3)
    w.render_panel.base_check.setChecked(False)  # tier 1's own frames (over the base, the edits' differences over the shot's rgb)
    w.act_untrained.setChecked(True)  # a model choice; builds the fake one in the background
    assert w.render_ctl.wait(TIMEOUT_MS) and w.render_ctl.renderer is not None
    w.doc.set_view("rendered")
    w.model = model
    yield w
    w.live.shutdown()
    w.render_ctl.cancel()
    w.render_ctl.wait(TIMEOUT_MS)


def expected(win, res) -> np.ndarray:
    """What tier 1 makes of the frame under the edits `res` was asked with (the library, not the editor)."""
    from x2video.conditioning.edited import apply_edits
    from x2video.tiers.residual import residual_frames

    return residual_frames(win.model.residual_net, [apply_edits(win.doc.shot, res.request.edits, res.t)])[0]


def test_a_slider_drag_previews_latest_wins_and_the_gui_never_blocks(qtbot, win, monkeypatch):
    import x2video.render.live as live_lib

    fast = live_lib.render_frame

    def slow(*args, **kwargs):  # in the worker: a frame slower than the inputs, so a queue would fall behind
        time.sleep(SLOW_S)
        return fast(*args, **kwargs)

    monkeypatch.setattr(live_lib, "render_frame", slow)
    live, slider = win.live, win.edit_panel.exposure
    shown: list = []
    live.sigShown.connect(lambda res: shown.append((time.perf_counter(), res)))
    probe = TickProbe(10)  # the GUI thread's tick-gap probe: a 10 ms timer's ticks stop while the thread blocks
    values = [round(v, 2) for v in np.linspace(-2.0, 2.0, 20)]
    probe.start()
    qtbot.wait(50)
    slider.setSliderDown(True)
    t0 = time.perf_counter()
    for i, v in enumerate(values):  # 20 values in 1 s
        slider.setValue(v)
        qtbot.wait(max(1, int(1000 * (t0 + 0.05 * (i + 1) - time.perf_counter()))))
        if i == len(values) - 1:
            last_input, last_version = time.perf_counter() - 0.05, win.doc.version
    slider.setSliderDown(False)
    qtbot.waitUntil(lambda: live.idle and live.shown is not None and live.shown.request.version == win.doc.version, timeout=TIMEOUT_MS)
    qtbot.wait(50)
    probe.stop()

    assert win.doc.edits.tuning(None)["exposure"] == pytest.approx(values[-1])
    # every preview shown is tier 1's frame of the edits it was asked with, newest last
    assert len(shown) >= 3 and all(res.frame.tier == "residual" for _, res in shown)
    ids = [res.request.id for _, res in shown]
    assert ids == sorted(set(ids))
    for _, res in shown:
        np.testing.assert_allclose(res.image, expected(win, res), rtol=1e-5, atol=1e-6)
    # once settled, what is shown is the latest value, at full quality (tier 1 is what auto renders), and marked
    last = live.shown
    assert last.request.version == last_version and last.request.edits.tuning(None)["exposure"] == pytest.approx(values[-1])
    assert win.doc.live is last and live.is_full(last)
    assert np.array_equal(win.doc.display_image(), channel_to_u8("rgb", expected(win, last), win.doc.size))
    assert live.badge.isVisible() and "full quality" in live.badge.text() and "full quality" in win.info_label.text()
    # latest-wins: each request that ran was the newest when it started; the rest were dropped, none waited behind
    p = live.previewer
    assert p.taken and all(rid == newest for rid, newest in p.taken)
    assert p.submitted == len(p.taken) + p.dropped and p.dropped >= 5 and len(p.taken) < len(values)
    reflect = next(at for at, res in shown if res.request.version == last_version)
    assert reflect - last_input < 3 * SLOW_S + 0.6, "the last value waited behind stale requests"
    # the GUI thread never blocked for more than 100 ms (of the time this process ran: the tests may share the machine
    # with work at a higher priority, whose time is no block of ours; on a quiet machine busy gaps are the wall gaps)
    wall, busy, _ = probe.gaps_ms()
    assert len(wall) > 20 and busy.max() < 100, f"GUI tick gaps: {probe.summary()}"
    assert not win.render_ctl.running and win.doc.render.status == "idle"


def test_a_local_prompt_shows_tier_1_at_once_then_the_samplers_frame(qtbot, win):
    live = win.live
    win.render_panel.preset.setCurrentIndex(win.render_panel.preset.findData("fast"))
    win.edits.add_mask()
    win.doc.set_mask_frame(0, win.doc.frame, np.ones(win.doc.size, np.float32))
    qtbot.waitUntil(lambda: live.idle, timeout=TIMEOUT_MS)
    shown: list = []
    live.sigShown.connect(shown.append)
    win.edits.set_local_prompt(0, "a brass lamp")
    qtbot.waitUntil(lambda: live.idle and any(r.frame.tier == "diffusion" for r in shown), timeout=TIMEOUT_MS)
    first, last = shown[0], shown[-1]
    assert first.frame.tier == "residual" and not live.is_full(first) and "stands in" in first.choice.preview.reason
    assert last.frame.tier == "diffusion" and last.request.final and live.is_full(last) and win.doc.live is last
    assert "diffusion, full quality" in live.badge.text() and not win.render_ctl.running


def test_auto_re_render_renders_the_shot_when_the_edits_rest(qtbot, win):
    live = win.live
    live.auto_box.setChecked(True)
    win.edits.set_param("exposure", 0.5, True)
    qtbot.waitUntil(lambda: win.doc.render.status == "finished", timeout=TIMEOUT_MS)
    assert win.doc.render.tier == "residual" and set(win.doc.render.frames) == set(range(5))
    qtbot.waitUntil(lambda: live.idle, timeout=TIMEOUT_MS)
    assert win.doc.live is None and not live.badge.isVisible()  # the render's frames are the edits' now


def test_live_off_renders_nothing_until_render(qtbot, win):
    live = win.live
    live.live_box.setChecked(False)
    win.edits.set_param("exposure", 0.5, True)
    qtbot.wait(2 * 250)
    assert live.idle and not live.history and live.previewer.submitted == 0 and win.doc.live is None
