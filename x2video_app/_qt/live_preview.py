"""Live preview (issue 43): while an edit control changes, the frame on screen re-renders off the GUI thread.

Every edit (slider drag, colour pick, brush stroke, mask-out toggle, exposure, tint, prompt, undo) asks
`LivePreviewer` (x2video_app._qt.live_previewer) for the frame on screen with the fastest tier auto trusts
(`x2video.render.live.preview_choice`: tier 1 where the render would use it, else the formula). The previewer is
latest-wins: it holds at most one request waiting, which the next one replaces (the stale one is dropped, never
queued), and one superqt generator worker drains it, so a preview in progress always finishes and shows while a
newer one waits. When the edits rest for `DEBOUNCE_MS`, the frame gets its full quality: the preview's own frame
where the render's tier is per-frame, else the sampler's window around it (`x2video.render.live.render_frame`). A
whole-shot render starts only on Render, or on settling when "Auto re-render" is ticked. The frame shows in the
rendered and side-by-side views, over the last render's frame, with a badge on the viewer saying it is a preview and
which tier made it.
"""
from __future__ import annotations

import sys
import time
from collections import deque
from typing import Any

from PySide6.QtCore import QObject, QTimer, Signal
from PySide6.QtWidgets import QCheckBox, QLabel

from x2video.render.settings import RenderSettings
from x2video_app._qt.live_previewer import LivePreviewer
from x2video_app.state.live_request import LiveRequest, LiveResult, snapshot_edits

#: quiet edits for this long = the person stopped: the frame on screen gets its full quality
DEBOUNCE_MS = 250
#: while a whole-shot render or its preparation runs, a settled frame that needs the sampler waits this long again
BUSY_RETRY_MS = 1000
#: the views that show rendered frames (`Document.rendered_u8`), where a live frame shows
LIVE_VIEWS = ("rendered", "side-by-side")
#: names the tiers go by on the badge
TIER_NAMES = {"formula": "formula", "residual": "tier 1", "diffusion": "diffusion"}


class LivePreview(QObject):
    """The editor's live preview: its toolbar (Live, Auto re-render), the debounce, the badge on the viewer.

    `win` is the main window; it reads its `doc`, `render_ctl`, `render_panel`, `viewer`, and calls `refresh_view`
    and `start_render`. sigShown(LiveResult) after the viewer shows a live frame (tests and bench.editor_latency)."""

    sigShown = Signal(object)

    def __init__(self, win: Any) -> None:
        super().__init__(win)
        self.win, self.doc, self.render_ctl = win, win.doc, win.render_ctl
        self.previewer = LivePreviewer(self)
        self.previewer.sigResult.connect(self._on_result)
        self.timer = QTimer(self)
        self.timer.setSingleShot(True)
        self.timer.setInterval(DEBOUNCE_MS)
        self.timer.timeout.connect(self.settle)
        self.live_box = QCheckBox("Live")
        self.live_box.setChecked(True)
        self.live_box.setToolTip("While you edit, re-render the frame on screen (tier 1 or the formula) in the rendered and "
                                 "side-by-side views; when you stop, it gets its full quality")
        self.live_box.toggled.connect(self._live_toggled)
        self.auto_box = QCheckBox("Auto re-render")
        self.auto_box.setToolTip("When you stop editing, render the whole shot again")
        self.toolbar = win.addToolBar("Live preview")
        self.toolbar.setObjectName("Live preview")
        self.toolbar.addWidget(self.live_box)
        self.toolbar.addWidget(self.auto_box)
        self.badge = QLabel(win.viewer)  # on the view, not its viewport, whose children scroll with the image
        self.badge.move(10, 10)
        self.badge.hide()
        self.shown: LiveResult | None = None  # what the viewer shows
        #: (seconds, LiveResult) of every live frame shown, for tests and the bench
        self.history: deque[tuple[float, LiveResult]] = deque(maxlen=10_000)
        self.errors = 0
        self._next_id = 0
        self._asked: tuple[int, int, bool] | None = None  # (frame, version, final) of the last request
        self._settled: tuple[int, int] | None = None  # (frame, version) whose per-frame preview is its full quality
        self._parked = False  # an edit waits for the model build
        self.settled_at: float | None = None  # when the edits last rested (perf_counter)
        self._opening = False
        self._render_version = -1  # the edits' version when the last whole-shot render started
        self.doc.edits_changed.connect(self._edits_changed)
        self.doc.frame_changed.connect(self._frame_changed)
        self.doc.shot_changed.connect(self._shot_changed)
        self.render_ctl.sigRunning.connect(self._running)
        self.render_ctl.sigPreload.connect(self._preloaded)
        self.previewer.cache = getattr(self.render_ctl.renderer, "cache", None)

    # -- when to ask -------------------------------------------------------------
    @property
    def idle(self) -> bool:
        """Nothing waits: no debounce pending, no request waiting or rendering."""
        return not self.timer.isActive() and not self.previewer.active and not self._parked

    def _edits_changed(self, kind: str) -> None:
        if kind == "display":  # a mask hidden or shown: nothing renders differently
            return
        if kind == "all" and self._opening:  # the shot (or project) just opened: nothing edited yet
            self._opening = False
            return
        self.poke()

    def _frame_changed(self, _t: int) -> None:
        if self.doc.live is not None:  # edited since the last render: the new frame on screen follows the edits too
            self.poke()

    def _shot_changed(self) -> None:
        self.previewer.cancel_final()
        self.timer.stop()
        self.doc.live = self.shown = None
        self._asked = self._settled = None
        self._opening, self._parked = True, False

    def _live_toggled(self, on: bool) -> None:
        if not on:
            self.previewer.cancel_final()
            self.timer.stop()
            self.doc.live = self.shown = None
            self.win.refresh_view()

    def poke(self) -> None:
        """The edits or the frame changed: a preview of the frame on screen now, its full quality once they rest."""
        if not self.live_box.isChecked() or self.doc.shot is None:
            return
        self.ask(final=False)
        self.timer.start(DEBOUNCE_MS)

    def _model(self) -> Any:
        return getattr(self.render_ctl.renderer, "model", None)  # None until built (a new model choice clears it)

    def _choice(self, settings: RenderSettings, model: Any) -> Any:
        if model is None:  # the worker decides (the tier modules import torch, which the window has not loaded)
            return None
        from x2video.render.live import preview_choice

        return preview_choice(settings.quality, self.doc.shot, self.doc.edits, model, settings.base)

    def ask(self, final: bool) -> bool:
        """Submit frame on screen under the current edits (a preview, or `final`: its full quality); False when it waits."""
        doc, model = self.doc, self._model()
        if model is None and (self.render_ctl.preload_worker is not None or "torch" not in sys.modules):
            # until a model is built: the tier modules import torch, which in a thread of ours would hold the GIL (the
            # window stalls) for seconds, and race a model build importing it too
            if not self._parked and self.render_ctl.preload_worker is None:
                self.win.status("Live preview starts once a model is loaded (Render menu: the untrained model for a smoke test).", 8000)
            self._parked = True
            return False
        settings = self.render_ctl.settings(**self.win.render_panel.values())
        self._next_id += 1
        self.previewer.cache = getattr(self.render_ctl.renderer, "cache", None)
        self.previewer.submit(LiveRequest(self._next_id, doc.frame, doc.version, final, doc.shot, snapshot_edits(doc.edits), settings,
                                          model, self._choice(settings, model), time.perf_counter()))
        self._asked = (doc.frame, doc.version, final)
        return True

    def settle(self) -> None:
        """The edits rested: the frame on screen at full quality (and the whole shot, with Auto re-render)."""
        doc = self.doc
        if doc.shot is None or not self.live_box.isChecked():
            return
        if self.auto_box.isChecked():
            if not self.render_ctl.running:
                self.win.start_render()
            return
        key = (doc.frame, doc.version)
        self.settled_at = time.perf_counter()
        model = self._model()
        settings = self.render_ctl.settings(**self.win.render_panel.values())
        choice = self._choice(settings, model)
        if choice is None or choice.full is None or choice.same:  # the preview's frame is all there is, or is the full one
            self._settled = key if choice is not None and choice.same else None
            if self._asked is None or self._asked[:2] != key:
                self.ask(final=False)
            self.win.refresh_view()
            return
        if self.render_ctl.running or self.render_ctl.prepare_worker is not None:  # the sampler is busy: later
            self.timer.start(BUSY_RETRY_MS)
            return
        self.ask(final=True)

    def _preloaded(self, busy: bool) -> None:
        if not busy and self._parked:
            self._parked = False
            self.poke()

    def _running(self, running: bool) -> None:
        if running:  # a whole-shot render: its frames are the edits' now
            self.previewer.cancel_final()
            self.timer.stop()
            self._render_version = self.doc.version
            self.doc.live = self.shown = None

    # -- showing -----------------------------------------------------------------
    def _on_result(self, res: LiveResult) -> None:
        req, doc = res.request, self.doc
        if res.frame is None:
            if res.error != "cancelled":
                self.errors += 1
                self.win.status(f"Live preview failed: {res.error}", 8000)
            return
        stale = self.shown is not None and req.id < self.shown.request.id
        if stale or req.version <= self._render_version or doc.shot is not req.shot or req.t != doc.frame or not self.live_box.isChecked():
            return
        self.shown = doc.live = res
        if doc.view in LIVE_VIEWS:
            self.win.refresh_view()
        self.history.append((time.perf_counter(), res))
        self.sigShown.emit(res)

    def is_full(self, res: LiveResult) -> bool:
        """Whether `res` is its frame at full quality (what the render's own tier makes)."""
        return (res.request.final and res.choice.full is not None) or (res.choice.same and self._settled == (res.t, res.request.version))

    def describe(self, res: LiveResult) -> str:
        tier = TIER_NAMES.get(res.frame.tier, res.frame.tier)
        return f"{tier}, full quality" if self.is_full(res) else f"live preview ({tier})"

    def mark(self, info_label: QLabel) -> None:
        """After the window refreshed the viewer: the badge, and the info label, say when a live frame is on screen."""
        res, doc = self.shown, self.doc
        comparing = getattr(getattr(self.win, "compare", None), "active", False)  # the Compare view labels its own sides
        if res is None or doc.live is not res or res.t != doc.frame or doc.view not in LIVE_VIEWS or comparing:
            self.badge.hide()
            return
        full = self.is_full(res)
        self.badge.setText(("" if full else "PREVIEW · ") + self.describe(res))
        self.badge.setToolTip(res.choice.preview.reason if not full else (res.choice.full or res.choice.preview).reason)
        self.badge.setStyleSheet("QLabel { background: %s; color: #111; padding: 2px 6px; border-radius: 3px; }"
                                 % ("#9fd49f" if full else "#ffb347"))
        self.badge.adjustSize()
        self.badge.show()
        self.badge.raise_()
        edited = "" if doc.version == res.request.version else " (your latest edit is on its way)"
        info_label.setText(f"frame {doc.frame}/{doc.num_frames - 1}: {self.describe(res)}{edited}")

    def shutdown(self) -> None:
        self.timer.stop()
        self.previewer.shutdown()
