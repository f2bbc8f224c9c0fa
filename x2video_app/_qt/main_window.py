"""The X2Video Studio main window: viewer, timeline, docks for masks/edits/scene/render/charts, menus (started by
`x2video_app._qt.launch`)."""
from __future__ import annotations

import logging
from operator import attrgetter
from pathlib import Path

from PySide6.QtCore import Qt, QTimer
from PySide6.QtGui import QKeySequence, QUndoStack
from PySide6.QtWidgets import QApplication, QCheckBox, QComboBox, QDockWidget, QHBoxLayout, QLabel, QMainWindow, QMessageBox, QPushButton, QVBoxLayout, QWidget
from shiboken6 import isValid

from x2video_app._qt.charts import Charts, pareto_path
from x2video_app._qt.compare import Compare
from x2video_app._qt.edit_actions import EditActions
from x2video_app._qt.edit_panel import EditPanel
from x2video_app._qt.export_controller import ExportController
from x2video_app._qt.live_preview import LivePreview
from x2video_app._qt.mask_panel import MaskPanel
from x2video_app._qt.project_controller import ProjectController
from x2video_app._qt.render_controller import RenderController
from x2video_app._qt.render_panel import RenderPanel
from x2video_app._qt.scene_panel import ScenePanel
from x2video_app._qt.timeline import Timeline
from x2video_app._qt.viewer import Viewer
from x2video_app._qt.window_render import WindowRender
from x2video_app.state.display import VIEW_MODES
from x2video_app.state.document import Document
from x2video_app.state.model_source import cuda_available, weights_hint

log = logging.getLogger(__name__)

#: signal -> slot of the window's parts (dotted attributes of the window): the viewer's and the panels' gestures that go
#: straight to an edit action or to the document, and the chosen tool back to the viewer and the mask panel
EDIT_WIRING: tuple[tuple[str, str], ...] = (
    ("viewer.sigPick", "edits.pick"),
    ("edits.sigTool", "viewer.set_tool"),
    ("edits.sigTool", "mask_panel.set_tool"),
    ("mask_panel.sigTool", "edits.set_tool"),
    ("mask_panel.sigBrushSize", "viewer.set_brush_radius"),
    ("mask_panel.sigAdd", "edits.add_mask"),
    ("mask_panel.sigRemove", "edits.remove_mask"),
    ("mask_panel.sigSelect", "doc.select_mask"),
    ("mask_panel.sigVisible", "edits.set_visible"),
    ("mask_panel.sigColour", "edits.set_mask_colour"),
    ("mask_panel.sigRename", "edits.rename_mask"),
    ("mask_panel.sigPrompt", "edits.set_local_prompt"),
    ("mask_panel.sigMaskOut", "edits.set_mask_out"),
    ("mask_panel.sigPropagate", "edits.propagate"),
    ("mask_panel.sigClearFrame", "edits.clear_frame"),
    ("edit_panel.sigParam", "edits.set_param"),
    ("edit_panel.sigTarget", "doc.set_edit_global"),
    ("edit_panel.sigReset", "edits.reset_params"),
    ("scene_panel.sigGlobalPrompt", "edits.set_global_prompt"),
    ("scene_panel.sigDrop", "edits.set_dropped"),
    ("scene_panel.sigLoadReference", "edits.load_reference_dialog"),
    ("scene_panel.sigUseRendered", "edits.use_rendered_reference"),
    ("scene_panel.sigClearReference", "edits.clear_reference"),
)
APP_NAME = "X2Video Studio"
BENCH_RESULTS = Path(__file__).resolve().parents[2] / "bench" / "results"


class MainWindow(QMainWindow):
    def __init__(self, bench_dir: Path | None = None, autosave_ms: int | None = None, preload: bool = True) -> None:
        """`preload`: start building the model as soon as the event loop runs (`launch` starts it itself,
        once the first shot is open)."""
        super().__init__()
        self.doc = Document()
        self.undo = QUndoStack(self)
        self.setWindowTitle(f"{APP_NAME}[*]")
        self.resize(1440, 900)
        self.ask = self._ask  # replaceable in tests: (title, text, buttons, default) -> button
        self.errors_shown: list[tuple[str, str]] = []  # (title, text) of every error dialog, for tests

        # central: view bar + viewer + timeline
        self.viewer = Viewer()
        self.view_box = QComboBox()
        for v in VIEW_MODES:
            self.view_box.addItem(v.replace("-", " "), v)
        self.view_box.setToolTip("Channel shown in the viewer (1-9, 0); intrinsic channels show your edits live")
        self.fit_button = QPushButton("Fit")
        self.follow_box = QCheckBox("Follow render")
        self.follow_box.setChecked(True)
        self.follow_box.setToolTip("While rendering, show each frame as it finishes")
        self.info_label = QLabel()
        self.info_label.setMinimumWidth(self.info_label.fontMetrics().horizontalAdvance("frame 0000/0000: not rendered (level 00)"))
        bar = QHBoxLayout()
        bar.setContentsMargins(4, 4, 4, 0)
        bar.addWidget(QLabel("View"))
        bar.addWidget(self.view_box)
        bar.addWidget(self.fit_button)
        bar.addWidget(self.follow_box)
        bar.addStretch(1)
        bar.addWidget(self.info_label)
        self.timeline = Timeline()
        central = QWidget()
        cl = QVBoxLayout(central)
        cl.setContentsMargins(0, 0, 0, 0)
        cl.setSpacing(2)
        cl.addLayout(bar)
        cl.addWidget(self.viewer, 1)
        cl.addWidget(self.timeline)
        self.setCentralWidget(central)

        # docks
        self.mask_panel = MaskPanel()
        self.edit_panel = EditPanel()
        self.scene_panel = ScenePanel()
        self.render_panel = RenderPanel()
        self.charts = Charts(bench_dir if bench_dir is not None else BENCH_RESULTS, pareto=pareto_path() if bench_dir is None else None)
        self.docks = {}
        for name, w, area in (
            ("Masks", self.mask_panel, Qt.DockWidgetArea.RightDockWidgetArea),
            ("Parametric edits", self.edit_panel, Qt.DockWidgetArea.RightDockWidgetArea),
            ("Scene", self.scene_panel, Qt.DockWidgetArea.RightDockWidgetArea),
            ("Render", self.render_panel, Qt.DockWidgetArea.LeftDockWidgetArea),
            ("Charts", self.charts, Qt.DockWidgetArea.LeftDockWidgetArea),
        ):
            d = QDockWidget(name, self)
            d.setObjectName(name)
            d.setWidget(w)
            d.setFeatures(QDockWidget.DockWidgetFeature.DockWidgetMovable | QDockWidget.DockWidgetFeature.DockWidgetFloatable)
            self.addDockWidget(area, d)
            self.docks[name] = d
        self.tabifyDockWidget(self.docks["Masks"], self.docks["Scene"])
        self.docks["Masks"].raise_()
        self.resizeDocks([self.docks["Render"], self.docks["Masks"]], [300, 380], Qt.Orientation.Horizontal)
        self.resizeDocks([self.docks["Render"], self.docks["Charts"]], [420, 380], Qt.Orientation.Vertical)
        self.model_status = QLabel()
        self.statusBar().addPermanentWidget(self.model_status)
        self.device_status = QLabel()
        self.device_status.setToolTip("Where the model runs (Render settings: Device)")
        self.statusBar().addPermanentWidget(self.device_status)
        self.render_panel.set_devices(cuda_available())

        # controllers
        self.render_ctl = RenderController(self.doc, self)
        self.rendering = WindowRender(self)  # model, device, the Render menu and what a render's events do here
        self.edits = EditActions(self.doc, self.undo, host=self, parent=self)
        self.project = ProjectController(self.doc, self.undo, self.render_ctl, host=self, parent=self, autosave_ms=autosave_ms)
        self.exporting = ExportController(self.doc, host=self, parent=self)  # MP4 / EXR sequence of the rendered frames
        self.live = LivePreview(self)  # the frame on screen re-renders while an edit changes (issue 43)
        self.compare = Compare(self)  # A/B wipe, side by side, difference; PSNR vs ground truth (issue 43)
        self._build_menus()
        self._connect()
        self.choose_default_model()
        self.refresh_all()
        if preload:
            QTimer.singleShot(0, self.render_ctl.preload)

    # -- construction ----------------------------------------------------------
    def _build_menus(self) -> None:
        mb = self.menuBar()
        f = mb.addMenu("&File")
        self.act_open_shot = f.addAction("Open shot…", self.project.open_shot_dialog, QKeySequence("Ctrl+Shift+O"))
        self.act_open_project = f.addAction("Open project…", self.project.open_project_dialog, QKeySequence.StandardKey.Open)
        self.act_open_demo = f.addAction("Open demo shot", self.project.open_demo)
        f.addSeparator()
        self.act_save = f.addAction("Save project", self.project.save, QKeySequence.StandardKey.Save)
        self.act_save_as = f.addAction("Save project as…", self.project.save_as, QKeySequence.StandardKey.SaveAs)
        f.addSeparator()
        self.act_export_mp4 = f.addAction("Export MP4…", lambda: self.exporting.export_dialog("mp4", self.render_panel.values()["exposure"]))
        self.act_export_exr = f.addAction("Export EXR sequence…", lambda: self.exporting.export_dialog("exr", self.render_panel.values()["exposure"]))
        f.addSeparator()
        f.addAction("Quit", self.close, QKeySequence.StandardKey.Quit)
        e = mb.addMenu("&Edit")
        self.act_undo = self.undo.createUndoAction(self, "Undo")
        self.act_undo.setShortcut(QKeySequence.StandardKey.Undo)
        self.act_redo = self.undo.createRedoAction(self, "Redo")
        self.act_redo.setShortcut(QKeySequence.StandardKey.Redo)
        e.addAction(self.act_undo)
        e.addAction(self.act_redo)
        e.addSeparator()
        for key, tool in (("B", "brush"), ("E", "eraser"), ("F", "fill"), ("P", "pan")):
            e.addAction(f"{tool.capitalize()} tool", lambda t=tool: self.edits.set_tool(t), QKeySequence(key))
        e.addAction("Smaller brush", lambda: self.mask_panel.size.setValue(max(1, self.mask_panel.size.value() - 2)), QKeySequence("["))
        e.addAction("Larger brush", lambda: self.mask_panel.size.setValue(self.mask_panel.size.value() + 2), QKeySequence("]"))
        e.addAction("Play / pause", self.timeline.play_button.toggle, QKeySequence("Space"))
        v = mb.addMenu("&View")
        for i, mode in enumerate(VIEW_MODES):
            a = v.addAction(mode, lambda m=mode: self.doc.set_view(m))
            a.setShortcut(QKeySequence(str((i + 1) % 10)))
        v.addSeparator()
        for d in self.docks.values():
            v.addAction(d.toggleViewAction())
        self.rendering.add_menu(mb)
        self.act_render, self.act_cancel, self.act_untrained = self.rendering.act_render, self.rendering.act_cancel, self.rendering.act_untrained
        h = mb.addMenu("&Help")
        h.addAction("About the model weights…", lambda: QMessageBox.information(self, "Model weights", weights_hint()))

    def _connect(self) -> None:
        doc = self.doc
        doc.frame_changed.connect(lambda t: self.refresh_view())
        doc.frame_changed.connect(self.timeline.set_current)
        doc.view_changed.connect(self._view_changed)
        doc.edits_changed.connect(self._edits_changed)
        doc.selection_changed.connect(self.refresh_panels)
        doc.shot_changed.connect(self._shot_changed)
        self.view_box.currentIndexChanged.connect(lambda i: doc.set_view(self.view_box.itemData(i)))
        self.fit_button.clicked.connect(self.viewer.fit)
        self.timeline.sigFrame.connect(doc.set_frame)
        self.viewer.sigHover.connect(self._hover)
        self.rendering.connect()
        self.project.sigTitle.connect(self._show_title)
        self._connect_edits()

    def _connect_edits(self) -> None:
        """The viewer's and the panels' gestures go to the edit actions; the chosen tool comes back to both (`EDIT_WIRING`)."""
        a, v = self.edits, self.viewer
        v.sigStrokePoint.connect(lambda x, y, starting: a.stroke_point(x, y, starting, v.brush_radius, v.tool == "eraser"))
        v.sigStrokeEnd.connect(lambda: a.stroke_end(v.tool == "eraser"))
        for signal, slot in EDIT_WIRING:
            attrgetter(signal)(self).connect(attrgetter(slot)(self))

    # -- rendering (x2video_app._qt.window_render) ------------------------------------
    def device(self) -> str:
        """The torch device renders use: the Render panel's choice, auto = cuda when available."""
        return self.rendering.device()

    def choose_default_model(self) -> None:
        self.rendering.choose_default_model()

    def start_render(self) -> bool:
        return self.rendering.start_render()

    def mark_chart(self, tier: str) -> dict | None:
        """Ring the running render's setting on the speed/accuracy chart (docs/pareto.json), at the shot's size."""
        return self.rendering.mark_chart(tier)

    @property
    def render_settings(self):
        """The last render's RenderSettings (the speed/accuracy chart marks it)."""
        return self.rendering.render_settings

    @render_settings.setter
    def render_settings(self, settings) -> None:
        self.rendering.render_settings = settings

    @property
    def first_frame_shown_s(self) -> float | None:
        """Seconds from pressing Render to the first frame painted in the viewer (last render)."""
        return self.rendering.first_frame_shown_s

    @property
    def first_keyframe_shown_s(self) -> float | None:
        """Seconds from pressing Render to the render's own first frame painted in the viewer (last render)."""
        return self.rendering.first_keyframe_shown_s

    # -- the controllers' host (x2video_app._qt.host.Host) and the title ------------------
    def status(self, text: str, timeout_ms: int = 0) -> None:
        self.statusBar().showMessage(text, timeout_ms)

    def _show_title(self, text: str, modified: bool) -> None:
        if isValid(self):  # the undo stack also reports while the window is being destroyed
            self.setWindowTitle(text)
            self.setWindowModified(modified)

    def _ask(self, title: str, text: str, buttons, default):
        return QMessageBox.question(self, title, text, buttons, default)

    def show_error(self, title: str, text: str) -> None:
        self.errors_shown.append((title, text))
        log.warning("%s: %s", title, text)
        if QApplication.platformName() == "offscreen":
            self.statusBar().showMessage(f"{title}: {text.splitlines()[0]}", 15000)
            return
        QMessageBox.critical(self, title, text)

    # -- refresh -----------------------------------------------------------------
    def _shot_changed(self) -> None:
        self.undo.clear()
        n = self.doc.num_frames
        fps = self.doc.shot.info.fps if self.doc.shot is not None else 10.0
        self.timeline.set_num_frames(n, fps)
        self.charts.reset(1)
        self.render_panel.set_base(self.doc.base_caption)
        self.refresh_all()
        self.rendering.prepare()

    def _view_changed(self, view: str) -> None:
        self.view_box.blockSignals(True)
        self.view_box.setCurrentIndex(VIEW_MODES.index(view))
        self.view_box.blockSignals(False)
        self.refresh_view()

    def _edits_changed(self, kind: str) -> None:
        self.refresh_view()
        if kind != "mask":
            self.refresh_panels()
        else:
            self._update_coverage()

    def refresh_all(self) -> None:
        has = self.doc.shot is not None
        for w in (self.mask_panel, self.edit_panel, self.scene_panel, self.render_panel.render_button, self.timeline):
            w.setEnabled(has)
        for a in (self.act_save, self.act_save_as, self.act_export_mp4, self.act_export_exr, self.act_render):
            a.setEnabled(has)
        self.refresh_view()
        self.refresh_panels()
        self.refresh_timeline()
        self.render_panel.show_state(self.doc.render)
        self.project.update_title()

    def refresh_view(self) -> None:
        self.viewer.set_image(self.compare.image_or(self.doc.display_image))
        s = self.doc.shot
        if s is not None:
            st, t = self.doc.render, self.doc.frame
            src = self.frame_sources()
            if src.base:  # the badge: path-traced, filled from the keyframes, and which tier edited it
                rendered = src.badge(t, t in st.frames) if t in st.frames or t not in st.preview else "formula preview"
                where = ""
            else:
                rendered = "rendered" if t in st.frames else "formula preview" if t in st.preview else "not rendered"
                lvl = st.levels.get(t)
                where = "" if lvl is None else " (one pass)" if lvl <= 0 else f" (level {lvl})"
            self.info_label.setText(f"frame {t}/{s.num_frames - 1}: {rendered}{where}")
            self.info_label.setToolTip(f"{s.size[1]}×{s.size[0]} pixels, {s.num_frames} frames at {s.info.fps:g} fps; {s.info.source}")
        self.live.mark(self.info_label)

    def frame_sources(self):
        """Where each frame comes from and which tier edited it (`x2video_app.state.frame_sources`), by the render's
        record, else by the Render panel's settings."""
        from x2video_app.state.frame_sources import frame_sources

        return frame_sources(self.doc.shot, self.render_ctl.settings(**self.render_panel.values()), self.doc.render)

    def refresh_timeline(self) -> None:
        st = self.doc.render
        self.timeline.set_num_frames(max(1, self.doc.num_frames), self.doc.shot.info.fps if self.doc.shot else 10.0)
        src = self.frame_sources()
        self.timeline.bar.set_state(max(1, self.doc.num_frames), st.keyframes, st.levels, st.top_level, st.in_flight, st.preview,
                                    src.keyframes, src.kinds)
        self.timeline.set_current(self.doc.frame)

    def refresh_panels(self) -> None:
        if self.doc.edits is None:
            return
        self.mask_panel.set_masks(self.doc.masks_summary(), self.doc.selected_mask)
        self._update_coverage()
        target = self.doc.edit_target()
        mask = None if target is None else self.doc.mask_name(target)
        name = "the whole frame" if mask is None else f"mask '{mask}'"
        e = self.doc.edits
        self.edit_panel.set_params(e.tuning(mask), name, mask is None, self.doc.selected_mask >= 0)
        ref_text = "No reference: the model follows the channels and prompts only." if e.reference is None else e.reference.describe()
        self.scene_panel.set_values(e.global_prompt, set(e.dropped), self.doc.reference_image(), ref_text)

    def _update_coverage(self) -> None:
        i = self.doc.selected_mask
        if i < 0 or self.doc.shot is None:
            self.mask_panel.set_coverage("Add a mask, then paint it in the viewer.")
            return
        mask = self.doc.edits.masks[self.doc.mask_name(i)]
        frames, ids = mask.painted_frames(), list(mask.ids)
        text = f"Painted on {len(frames)} of {self.doc.num_frames} frames"
        if ids:
            caps = self.doc.shot.info.object_captions
            text += "; objects on every frame: " + ", ".join(f"{o}" + (f" ({caps[o]})" if o in caps else "") for o in ids)
        self.mask_panel.set_coverage(text)

    def _hover(self, x: float, y: float) -> None:
        if self.doc.shot is None:
            return
        h, w = self.doc.size
        xi, yi = int(x), int(y)
        if 0 <= xi < w and 0 <= yi < h:
            msg = f"x {xi}  y {yi}"
            if self.doc.shot.has("ids"):
                oid = int(self.doc.shot.channel("ids", self.doc.frame)[yi, xi, 0])
                cap = self.doc.shot.info.object_captions.get(oid, "")
                msg += f"  object {oid}" + (f" ({cap})" if cap else "")
            self.statusBar().showMessage(msg, 3000)

    # -- closing -----------------------------------------------------------------
    def closeEvent(self, ev) -> None:
        if not self.project.confirm_discard("quit"):
            ev.ignore()
            return
        self.edits.cancel_propagation()
        if self.render_ctl.busy:
            self.render_ctl.cancel()
            self.render_ctl.wait(120000)
        self.live.shutdown()
        self.compare.shutdown()
        self.project.shutdown()
        ev.accept()

