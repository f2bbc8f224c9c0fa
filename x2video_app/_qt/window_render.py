"""The main window's side of rendering: which model and device renders use, the Render menu and button, and what a
render's events and errors do to the window (status bar, charts, viewer, timeline). The window composes one
(`MainWindow.rendering`); the render itself runs in `RenderController`."""
from __future__ import annotations

import dataclasses
import logging
import time
from typing import Any

from PySide6.QtCore import QObject, QTimer
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import QMenuBar, QMessageBox

from x2video.render.events import FramesReady, RenderStarted, WindowStarted
from x2video_app._qt.charts import pareto_key
from x2video_app.state.model_source import ModelChoice, has_weights, resolve_device, weights_dir, weights_hint
from x2video_app.state.preview import PreviewReady

log = logging.getLogger(__name__)


class WindowRender(QObject):
    """Render wiring of `win` (the main window: its doc, render_ctl, render_panel, charts, viewer, status widgets)."""

    def __init__(self, win: Any) -> None:
        super().__init__(win)
        self.win = win
        self.render_settings = None  # the last render's RenderSettings (the speed/accuracy chart marks it)
        #: seconds from pressing Render to the first frame painted in the viewer, the formula's preview or the
        #: render's own (last render)
        self.first_frame_shown_s: float | None = None
        #: seconds from pressing Render to the render's first frame painted in the viewer (a keyframe in the
        #: recursive scheme; the first batch of a per-frame tier) (last render)
        self.first_keyframe_shown_s: float | None = None
        self._eta_timer = QTimer(self)
        self._eta_timer.timeout.connect(lambda: win.render_panel.show_state(win.doc.render))

    def add_menu(self, mb: QMenuBar) -> None:
        """The Render menu: Render, Cancel, and the untrained model for a smoke test."""
        w = self.win
        r = mb.addMenu("&Render")
        self.act_render = r.addAction("Render", self.start_render, QKeySequence("Ctrl+R"))
        self.act_cancel = r.addAction("Cancel render", w.render_ctl.cancel, QKeySequence("Esc"))
        r.addSeparator()
        self.act_untrained = QAction("Use the UNTRAINED tiny model (smoke test)", w, checkable=True)
        self.act_untrained.toggled.connect(self._untrained_toggled)
        r.addAction(self.act_untrained)

    def connect(self) -> None:
        """The Render panel's and the render controller's signals."""
        w = self.win
        w.render_panel.sigRender.connect(self.start_render)
        w.render_panel.sigCancel.connect(w.render_ctl.cancel)
        w.render_panel.sigDevice.connect(self._device_changed)
        w.render_panel.sigSettingsChanged.connect(self.prepare)
        w.render_ctl.sigEvent.connect(self._render_event)
        w.render_ctl.sigRunning.connect(self._running)
        w.render_ctl.sigError.connect(self._render_error)
        w.render_ctl.sigPreload.connect(self._preloading)

    # -- model -----------------------------------------------------------------
    def device(self) -> str:
        """The torch device renders use: the Render panel's choice, auto = cuda when available."""
        return resolve_device(self.win.render_panel.device.currentData())

    def _device_changed(self, _choice: str) -> None:
        c = self.win.render_ctl.choice
        if c is not None:
            self.win.render_ctl.set_model(dataclasses.replace(c, device=self.device()))  # a new Renderer on that device
            self.win.render_ctl.preload()
        self._update_model_label()

    def choose_default_model(self) -> None:
        w, d = self.win, weights_dir()
        if has_weights(d):
            w.render_ctl.set_model(ModelChoice("pretrained", d, device=self.device()))
            w.model_status.setText(f"Model: {d}")
        else:
            w.render_ctl.set_model(None)
            w.statusBar().showMessage(f"Model weights not found in {d}; renders need them (or the untrained tiny model for a smoke test).", 15000)
        self._update_model_label()

    def _untrained_toggled(self, on: bool) -> None:
        if on:
            self.win.render_ctl.set_model(ModelChoice("untrained", device=self.device()))
        else:
            self.choose_default_model()
        self._update_model_label()
        self.win.render_ctl.preload()

    def _preloading(self, busy: bool) -> None:
        w = self.win
        w.statusBar().showMessage("Loading the model in the background…" if busy else "Model loaded.", 0 if busy else 4000)
        if not busy:
            w.render_panel.set_residual_available(w.render_ctl.residual_available())

    def _update_model_label(self) -> None:
        w = self.win
        c = w.render_ctl.choice
        text = c.label if c is not None else "Model: none (weights missing)"
        tip = c.detail if c is not None else "No trained weights found; Render offers the untrained tiny model."
        w.model_status.setText(text)
        w.model_status.setMinimumWidth(w.model_status.fontMetrics().horizontalAdvance(text) + 28)
        w.model_status.setToolTip(tip)
        w.render_panel.model_label.setText(text)
        w.render_panel.model_label.setToolTip(tip)
        w.render_panel.model_label.setStyleSheet("color: #ffb347;" if c is None or c.kind == "untrained" else "")
        w.device_status.setText(f"Device: {self.device()}")
        w.render_panel.set_residual_available(w.render_ctl.residual_available())

    # -- rendering ---------------------------------------------------------------
    def prepare(self) -> None:
        """Encode the shot's conditioning in the background for a render with the panel's settings (issue 31)."""
        w = self.win
        if w.doc.shot is not None and not w.render_ctl.running:
            w.render_ctl.prepare(w.render_ctl.settings(**w.render_panel.values()))

    def start_render(self) -> bool:
        w = self.win
        if w.doc.shot is None or w.render_ctl.running:
            return False
        if w.render_ctl.choice is None:
            b = w.ask(
                "Model weights missing",
                weights_hint() + "\n\nRender with the untrained tiny model now?",
                QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.Cancel,
                QMessageBox.StandardButton.Cancel,
            )
            if b != QMessageBox.StandardButton.Yes:
                return False
            self.act_untrained.setChecked(True)
        settings = w.render_ctl.settings(**w.render_panel.values())
        self.render_settings = settings  # the chart marks this setting when the render says which tier runs
        if w.follow_box.isChecked() and w.doc.view not in ("rendered", "side-by-side"):
            w.doc.set_view("rendered")
        self.first_keyframe_shown_s = self.first_frame_shown_s = None
        ok = w.render_ctl.start(settings)
        if ok:
            w.charts.reset(1)
            w.refresh_timeline()
        return ok

    def _running(self, running: bool) -> None:
        w = self.win
        w.render_panel.set_running(running)
        self.act_render.setEnabled(not running)
        self.act_cancel.setEnabled(running)
        if running:
            self._eta_timer.start(500)
        else:
            self._eta_timer.stop()
            w.render_panel.set_residual_available(w.render_ctl.residual_available())  # the render may have built the model
        w.render_panel.show_state(w.doc.render)
        w.refresh_timeline()

    def mark_chart(self, tier: str) -> dict | None:
        """Ring the running render's setting on the speed/accuracy chart (docs/pareto.json), at the shot's size."""
        w = self.win
        settings, model = self.render_settings, getattr(w.render_ctl.renderer, "model", None)
        if settings is None or w.doc.shot is None or tier == "base":  # base: no tier ran, the shot's own frames (x2video.base.stage)
            return None
        if model is not None:
            from x2video.tiers import registry as tiers  # the preset as the tier resolves it

            settings = tiers.get(tier).with_preset(settings, model)
        h, wd = w.doc.shot.size
        return w.charts.mark_setting(pareto_key(tier, settings), (wd, h))

    def _shown_after_press(self) -> float | None:
        """Paint the viewer now; seconds since Render was pressed."""
        w = self.win
        if w.render_ctl.pressed_at is None:
            return None
        w.viewer.viewport().repaint()
        return time.perf_counter() - w.render_ctl.pressed_at

    def _render_event(self, ev) -> None:
        w = self.win
        st = w.doc.render
        if isinstance(ev, PreviewReady):  # the formula's frames, until the render's own arrive; the viewer stays put
            if w.doc.frame in ev.frames:
                w.refresh_view()
                if self.first_frame_shown_s is None:
                    self.first_frame_shown_s = self._shown_after_press()
        elif isinstance(ev, RenderStarted):
            w.charts.reset(0 if st.per_frame else max(ev.levels) if ev.levels else 1, ev.num_windows)
            w.statusBar().showMessage(f"Rendering with the {ev.tier} tier" + (f": {ev.reason}" if ev.reason else ""), 15000)
            self.mark_chart(ev.tier)
            log.info("render tier %s (%s)", ev.tier, ev.reason)
        elif isinstance(ev, FramesReady):
            w.charts.add_window(ev.window, 0 if st.per_frame else ev.level, ev.seconds)
            if w.follow_box.isChecked():
                w.doc.set_frame(min(ev.frames))
            if w.doc.frame in ev.frames:
                w.refresh_view()
            if self.first_keyframe_shown_s is None:
                self.first_keyframe_shown_s = self._shown_after_press()
                if self.first_frame_shown_s is None:
                    self.first_frame_shown_s = self.first_keyframe_shown_s
                if self.first_keyframe_shown_s is not None:
                    log.info("first frame of the render on screen %.2f s after Render was pressed", self.first_keyframe_shown_s)
        elif isinstance(ev, WindowStarted):
            pass
        w.render_panel.show_state(st)
        w.refresh_timeline()
        if st.status in ("finished", "cancelled", "failed"):
            w.refresh_view()
            w.statusBar().showMessage(w.render_panel.status_label.text().replace("\n", "  "), 10000)

    def _render_error(self, kind: str, message: str) -> None:
        w = self.win
        if kind == "weights":
            self.act_untrained.setChecked(False)
            b = w.ask("Model weights missing", message + "\n\nUse the untrained tiny model instead?",
                      QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No, QMessageBox.StandardButton.No)
            if b == QMessageBox.StandardButton.Yes:
                self.act_untrained.setChecked(True)
        elif kind == "oom":
            w.show_error("Out of memory", "The render ran out of memory:\n" + message +
                         "\n\nYour project is intact. Try a smaller window N, a shorter frame range, the fast preset, "
                         "or close other programs, then render again.")
        else:
            w.show_error("Render failed", message + "\n\nYour project is intact; frames that finished are kept.")
