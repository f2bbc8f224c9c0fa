"""Editor building blocks on their own: display transforms, viewer input, timeline marks, charts, render state."""
import json

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from PySide6.QtCore import QPoint, QPointF, Qt  # noqa: E402

from x2video.render.events import FramesReady, RenderFinished, RenderStarted, StepDone, WindowStarted  # noqa: E402
from x2video.render.settings import RenderSettings
from x2video_app._qt.charts import Charts, find_bench_points, pareto_key  # noqa: E402
from x2video_app._qt.timeline import Timeline  # noqa: E402
from x2video_app._qt.viewer import Viewer  # noqa: E402
from x2video_app.state.display import channel_to_u8, ids_palette, overlay_masks, side_by_side  # noqa: E402
from x2video_app.state.render_state import RenderState  # noqa: E402


def test_display_transforms():
    alb = np.full((4, 6, 3), 0.214, np.float32)  # linear 0.214 ~ sRGB 0.5
    u8 = channel_to_u8("albedo", alb, (4, 6))
    assert u8.dtype == np.uint8 and u8.shape == (4, 6, 3) and abs(int(u8[0, 0, 0]) - 128) <= 1
    n = np.zeros((4, 6, 3), np.float32)
    n[..., 2] = 1
    assert tuple(channel_to_u8("normal", n, (4, 6))[0, 0]) == (128, 128, 255)
    assert channel_to_u8("albedo", None, (4, 6)).shape == (4, 6, 3)  # dropped: checkerboard
    ids = np.array([[0, 1], [2, 1]], np.int32)
    pal = ids_palette(ids)
    assert (pal[0, 0] == 0).all() and (pal[0, 1] == pal[1, 1]).all() and not (pal[0, 1] == pal[1, 0]).all()
    base = np.zeros((8, 8, 3), np.uint8)
    m = np.zeros((8, 8), np.float32)
    m[2:6, 2:6] = 1
    over = overlay_masks(base, [(m, (255, 0, 0))])
    assert over[0, 0].sum() == 0 and over[4, 4, 0] > 0 and over[2, 2, 0] == 255
    assert side_by_side(base, base, gap=4).shape == (8, 20, 3)


def test_viewer_zoom_and_stroke_signals(qtbot):
    v = Viewer()
    qtbot.addWidget(v)
    v.resize(400, 300)
    v.show()
    img = np.zeros((64, 80, 3), np.uint8)
    img[:, 40:] = 200
    v.set_image(img)
    z0 = v.zoom_level
    v.zoom(2.0)
    assert v.zoom_level == pytest.approx(2 * z0)
    v.fit()
    v.set_tool("brush")
    pts = []
    v.sigStrokePoint.connect(lambda x, y, s: pts.append((x, y, s)))
    centre = v.mapFromScene(QPointF(40, 32))
    with qtbot.waitSignal(v.sigStrokeEnd):
        qtbot.mousePress(v.viewport(), Qt.MouseButton.LeftButton, pos=centre)
        qtbot.mouseMove(v.viewport(), centre + QPoint(20, 0))
        qtbot.mouseRelease(v.viewport(), Qt.MouseButton.LeftButton, pos=centre + QPoint(20, 0))
    assert pts[0][2] is True and abs(pts[0][0] - 40) < 2 and abs(pts[0][1] - 32) < 2
    with pytest.raises(ValueError, match="unknown tool"):
        v.set_tool("lasso")


def test_timeline_scrub_and_play(qtbot):
    tl = Timeline()
    qtbot.addWidget(tl)
    tl.resize(600, 50)
    tl.show()
    tl.set_num_frames(20, fps=50)
    tl.bar.set_state(20, {0, 10, 19}, {0: 2, 10: 2, 19: 2, 5: 1}, 2)
    got = []
    tl.sigFrame.connect(got.append)
    bar = tl.bar
    qtbot.mouseClick(bar, Qt.MouseButton.LeftButton, pos=QPoint(int(bar._x(10.5)), 20))
    assert got[-1] == 10
    tl.set_current(3)
    with qtbot.waitSignal(tl.sigFrame, timeout=2000) as blocker:
        tl.play_button.setChecked(True)
    assert blocker.args == [4]
    tl.stop()


def test_bench_points_found_in_nested_results(tmp_path, qtbot):
    res = {"rows": [{"name": "DDIM-20", "seconds_per_frame": 2.0, "psnr": 24.1}, {"name": "LCM-2", "seconds_per_frame": 0.3, "psnr": 22.0}],
           "other": {"psnr": 1.0}}
    (tmp_path / "render.json").write_text(json.dumps(res))
    (tmp_path / "broken.json").write_text("{not json")
    assert sorted(p[0] for p in find_bench_points(res)) == ["DDIM-20", "LCM-2"]
    c = Charts(tmp_path)
    qtbot.addWidget(c)
    assert "2 settings" in c.bench_note.text()
    c.reset(2)
    c.add_window(0, 2, 1.5)
    c.add_window(1, 1, 0.7)
    assert c.windows == [(0, 2, 1.5), (1, 1, 0.7)]


def test_pareto_chart_marks_the_current_setting_at_the_nearest_size(tmp_path, qtbot):
    rows = [{"method": m, "label": lab, "family": fam, "size": list(size), "seconds_per_frame": spf, "psnr": db}
            for size in ((160, 112), (320, 224)) for m, lab, fam, spf, db in
            (("formula", "formula (tier 0)", "formula", 0.002, 23.5), ("ddim-4", "DDIM-4", "ddim-recursive", 1.5, 22.0),
             ("lcm-2", "LCM-2", "lcm-recursive", 0.5 * size[0] / 160, 21.0), ("cycles-64", "Cycles 64 spp + OIDN", "cycles", 20.0, 35.0))]
    path = tmp_path / "pareto.json"
    seq = {"method": "lcm-2-seq", "label": "LCM-2 sequential", "family": "lcm-sequential", "size": [160, 112], "seconds_per_frame": 0.45,
           "psnr": 24.59}
    path.write_text(json.dumps({"format": "x2video-pareto", "rows": rows, "sections": {"long shot": {"rows": [seq]}}}))
    c = Charts(tmp_path, pareto=path)
    qtbot.addWidget(c)
    assert "4 settings" in c.bench_note.text()
    mark = c.mark_setting(pareto_key("diffusion", RenderSettings(sampler="lcm", steps=2)), (300, 200))
    assert mark is not None and mark["size"] == [320, 224] and mark["seconds_per_frame"] == 1.0 and c.marked is mark
    assert "LCM-2" in c.bench_note.text() and "320x224" in c.bench_note.text()
    assert c.mark_setting("ddim-7", (160, 112)) is None and "not among the measured" in c.bench_note.text()
    assert c.mark_setting(pareto_key("diffusion", RenderSettings(sampler="lcm", steps=2, scheme="sequential")), (160, 112)) is None
    assert "section 'long shot'" in c.bench_note.text() and "24.59 dB" in c.bench_note.text()
    assert c.mark_setting("lcm-2-seq", (320, 224)) is None and "not among the measured" in c.bench_note.text()  # not at that size
    assert c.mark_setting(pareto_key("formula", RenderSettings()), (160, 112))["psnr"] == 23.5
    assert Charts(tmp_path, pareto=tmp_path / "missing.json").pareto is None  # falls back to the bench points


def test_render_state_tracks_levels_keyframes_and_eta():
    st = RenderState()
    seen = []
    st.changed.connect(seen.append)
    st.begin(steps_per_window=2, windows_per_level={2: 1, 1: 2})
    st.apply(RenderStarted(num_frames=9, num_windows=3, levels=[2, 1]))
    st.apply(WindowStarted(index=0, frames=[0, 4, 8], mode="key", level=2))
    assert st.in_flight == [0, 4, 8]
    st.apply(StepDone(window=0, step=1, steps=2))
    assert st.eta_seconds() is not None
    img = np.zeros((2, 2, 3), np.float32)
    st.apply(FramesReady(window=0, frames={0: img, 4: img, 8: img}, level=2, mode="key", seconds=0.1))
    st.apply(FramesReady(window=1, frames={1: img, 2: img, 3: img}, level=1, mode="interp", seconds=0.1))
    assert st.keyframes == {0, 4, 8} and st.levels[2] == 1 and st.top_level == 2
    assert st.level_progress() == [(2, 1, 1), (1, 1, 2)]
    st.apply(RenderFinished(num_frames=6, seconds=0.2))
    assert st.status == "finished" and st.time_to_first_keyframe() is not None
    assert [a[2] for a in st.arrivals] == ["key"] * 3 + ["interp"] * 3
    assert len(seen) == 7


def test_render_state_is_per_frame_when_its_tier_says_so():
    """Per frame is what RenderStarted says (any tier's `per_frame`), not a list of tier names."""
    st = RenderState()
    st.begin(steps_per_window=1, windows_per_level={1: 3})
    st.apply(RenderStarted(num_frames=3, num_windows=0, levels=[0], tier="toy-grey", per_frame=True))
    assert st.per_frame and st.windows_per_level == {} and st.level_order == [0]
    st.begin(steps_per_window=2)
    assert not st.per_frame
    st.apply(RenderStarted(num_frames=9, num_windows=3, levels=[2, 1], tier="diffusion"))
    assert not st.per_frame


def test_render_state_seam_pass_replaces_keyframes():
    """The seam pass makes keyframe 4 again in an interpolation window, and frame 0 in a lower-level
    keyframe-mode window: neither is a keyframe any more, and the viewer shows the new frames."""
    st = RenderState()
    st.begin(steps_per_window=1)
    st.apply(RenderStarted(num_frames=9, num_windows=3, levels=[3, 2]))
    old, new = np.zeros((2, 2, 3), np.float32), np.ones((2, 2, 3), np.float32)
    st.apply(FramesReady(window=0, frames={0: old, 4: old, 8: old}, level=3, mode="key", seconds=0.1))
    st.apply(FramesReady(window=1, frames={2: new, 4: new, 6: new}, level=2, mode="interp", seconds=0.1, replaces=(4,)))
    st.apply(FramesReady(window=2, frames={1: new, 0: new}, level=2, mode="key", seconds=0.1, replaces=(0,)))
    assert st.keyframes == {8} and st.levels[4] == 2 and float(st.frames[4].max()) == 1.0


def test_render_panel_seam_pass_only_with_the_recursive_scheme(qtbot):
    from x2video_app._qt.render_controller import RenderController
    from x2video_app._qt.render_panel import RenderPanel

    panel = RenderPanel()
    qtbot.addWidget(panel)
    changed = []
    panel.sigSettingsChanged.connect(lambda: changed.append(1))
    assert panel.values()["seams"] is True and panel.seams.isEnabled()  # RenderSettings' default
    panel.seams.setChecked(False)
    assert panel.values()["seams"] is False and changed
    panel.seams.setChecked(True)
    assert panel.values()["seams"] is True and changed
    settings = RenderController.settings(None, **panel.values())  # type: ignore[arg-type]  (does not touch self)
    assert settings.seams and settings.scheme == "recursive"
    panel.scheme.setCurrentIndex(panel.scheme.findData("sequential"))
    assert not panel.seams.isEnabled() and panel.values()["seams"] is False


def test_render_panel_noise_shared_reaches_the_settings(qtbot):
    from x2video.render.settings import RenderSettings
    from x2video_app._qt.render_controller import RenderController
    from x2video_app._qt.render_panel import RenderPanel

    panel = RenderPanel()
    qtbot.addWidget(panel)
    changed = []
    panel.sigSettingsChanged.connect(lambda: changed.append(1))
    assert panel.values()["noise_shared"] == RenderSettings.noise_shared
    panel.noise_shared.setValue(0.5)
    settings = RenderController.settings(None, **panel.values())  # type: ignore[arg-type]  (does not touch self)
    assert changed and settings.noise == "frame" and settings.noise_shared == 0.5
    panel.noise_shared.setValue(1.7)  # clamped to the range the Renderer accepts
    assert panel.values()["noise_shared"] == 1.0


def test_render_panel_max_levels_reaches_the_settings(qtbot):
    from x2video_app._qt.render_controller import RenderController
    from x2video_app._qt.render_panel import RenderPanel

    panel = RenderPanel()
    qtbot.addWidget(panel)
    changed = []
    panel.sigSettingsChanged.connect(lambda: changed.append(1))
    assert panel.values()["max_levels"] is None and panel.levels.text() == "auto"  # the Renderer's default
    panel.levels.setValue(2)
    settings = RenderController.settings(None, **panel.values())  # type: ignore[arg-type]  (does not touch self)
    assert changed and settings.max_levels == 2 and settings.scheme == "recursive"
    panel.scheme.setCurrentIndex(panel.scheme.findData("sequential"))
    assert not panel.levels.isEnabled() and panel.values()["max_levels"] is None


def test_mask_overlay_reads_as_a_selection():
    """Outside every mask the image is dimmed and desaturated, inside tinted, the edge outlined in the mask's colour
    with a dark line outside it; no mask, no change."""
    base = np.full((12, 12, 3), (40, 200, 120), np.uint8)
    m = np.zeros((12, 12), np.float32)
    m[3:9, 3:9] = 1
    over = overlay_masks(base, [(m, (255, 99, 71))])
    outside, inside = over[0, 0].astype(int), over[5, 5].astype(int)
    assert outside.sum() < base[0, 0].astype(int).sum() * 0.6 and np.ptp(outside) < np.ptp(base[0, 0].astype(int))
    assert inside[0] > 150 and abs(int(inside[1]) - 200) > 40  # tinted towards the mask's colour
    assert tuple(over[3, 5]) == (255, 99, 71) and tuple(over[2, 5]) == (51, 19, 14)  # the outline, the dark line outside
    assert np.array_equal(overlay_masks(base, [(np.zeros((12, 12)), (255, 0, 0))]), base)


def test_mask_list_shows_each_masks_prompt_after_its_name(qtbot):
    from PySide6.QtWidgets import QStyleOptionViewItem

    from x2video_app._qt.mask_panel import MaskPanel

    panel = MaskPanel()
    qtbot.addWidget(panel)
    panel.set_masks([{"name": "mask 1", "colour": (255, 0, 0), "visible": True, "prompt": "a red sofa", "mask_out": False},
                     {"name": "mask 2", "colour": (0, 0, 255), "visible": True, "prompt": "", "mask_out": True}], 0)

    def shown(row: int) -> str:
        opt = QStyleOptionViewItem()
        panel.list.itemDelegate().initStyleOption(opt, panel.list.model().index(row, 0))
        return opt.text

    assert shown(0) == "mask 1  \u2014  \u201ca red sofa\u201d" and shown(1) == "mask 2  \u2014  A|M|R out"
    assert panel.list.item(0).text() == "mask 1"  # renaming edits the name alone
    renamed = []
    panel.sigRename.connect(lambda i, name: renamed.append((i, name)))
    panel.list.item(0).setText("sofa")
    assert renamed == [(0, "sofa")]


def _docked_render_panel(qtbot, height: int):
    """A main window with the Render panel docked above another dock, as the editor lays them out."""
    from PySide6.QtWidgets import QDockWidget, QMainWindow, QWidget

    from x2video_app._qt.render_panel import RenderPanel

    win = QMainWindow()
    qtbot.addWidget(win)
    win.setCentralWidget(QWidget())
    panel, below = RenderPanel(), QWidget()
    below.setMinimumHeight(150)
    for name, w in (("Render", panel), ("Charts", below)):
        d = QDockWidget(name, win)
        d.setWidget(w)
        win.addDockWidget(Qt.DockWidgetArea.LeftDockWidgetArea, d)
    win.resizeDocks([panel.parentWidget(), below.parentWidget()], [300, 600], Qt.Orientation.Vertical)  # the panel too short
    win.resize(1000, height)
    win.show()
    qtbot.waitExposed(win)
    qtbot.wait(50)
    return win, panel, below


def _long_render_state() -> RenderState:
    st = RenderState()
    st.begin(steps_per_window=2, windows_per_level={3: 1, 2: 5, 1: 8})
    st.apply(RenderStarted(num_frames=33, num_windows=14, levels=[3, 2, 1], tier="diffusion",
                           reason="albedo/material masked out (A|M|R) inside mask(s) mask 2; local prompt(s) on mask 1, "
                                  "mask 2: generated there, tier 1 around it"))
    st.apply(FramesReady(window=0, frames={0: np.zeros((2, 2, 3), np.float32)}, level=3, mode="key", seconds=1.0))
    return st


def test_render_panel_rows_keep_their_height_when_progress_bars_show(qtbot):
    win, panel, below = _docked_render_panel(qtbot, 900)
    rows = (panel.quality, panel.preset, panel.seed, panel.window, panel.scheme, panel.levels, panel.noise_shared, panel.device,
            panel.render_button)
    before = [w.height() for w in rows]
    assert all(h >= w.sizeHint().height() for h, w in zip(before, rows))  # the dock grew to the rows on show
    assert panel.scroll.verticalScrollBar().maximum() == 0
    below_before = below.height()
    panel.show_state(_long_render_state())
    qtbot.wait(50)
    assert [w.height() for w in rows] == before
    bars = list(panel._bars.values())
    assert len(bars) == 3 and all(b.height() >= b.sizeHint().height() for b in bars)
    label = panel.status_label
    assert "Tier: diffusion" in label.text() and label.height() >= label.heightForWidth(label.width())
    assert panel.scroll.verticalScrollBar().maximum() == 0 and below.height() <= below_before  # room from the dock below


def test_render_panel_scrolls_instead_of_squeezing_in_a_short_window(qtbot):
    win, panel, below = _docked_render_panel(qtbot, 420)
    panel.show_state(_long_render_state())
    qtbot.wait(50)
    for w in (panel.quality, panel.seed, panel.device, *panel._bars.values()):
        assert w.height() >= w.sizeHint().height()
    assert panel.scroll.verticalScrollBar().maximum() > 0 and below.height() >= below.minimumHeight()


def test_render_panel_shows_the_base_and_turns_it_off(qtbot):
    from x2video_app._qt.render_controller import RenderController
    from x2video_app._qt.render_panel import RenderPanel

    panel = RenderPanel()
    qtbot.addWidget(panel)
    assert panel.base_check.isHidden()  # no shot with path-traced frames
    panel.set_base("Base: the shot's path-traced frames (rgb on every frame)")
    assert not panel.base_check.isHidden() and "path-traced" in panel.base_check.text()
    assert RenderController.settings(None, **panel.values()).base == "auto"  # type: ignore[arg-type]  (does not touch self)
    changed = []
    panel.sigSettingsChanged.connect(lambda: changed.append(1))
    panel.base_check.setChecked(False)
    assert changed and RenderController.settings(None, **panel.values()).base == "off"  # type: ignore[arg-type]
    panel.set_base("")
    assert panel.base_check.isHidden()
