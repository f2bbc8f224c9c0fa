"""Views a look-dev user expects (issue 43): A/B wipe, side by side and a false-colour difference between any two of the
frame's versions, and per-frame PSNR against the ground truth in the status bar.

The versions (`SOURCES`) of the frame on screen: the edited channel last viewed, the formula and tier 1 of the current
edits (made off the GUI thread by a `LivePreviewer` of its own, the library's `render_frame` with that tier forced),
the diffusion sampler's frame (the last render's when it ran that tier, or the live preview's full-quality one), what
the rendered view shows, the reference frame, and the ground truth (the shot's `rgb` channel: the Cycles render of a
path-traced shot) where the shot has one. The Compare toolbar picks A, B, the mode and the wipe's position; the
window shows `image_or(...)` instead of its own view while a mode is on.
"""
from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np
from PySide6.QtCore import QObject, Qt
from PySide6.QtWidgets import QComboBox, QLabel, QSlider

from x2video.channels import INTRINSIC, tonemap
from x2video_app._qt.live_previewer import LivePreviewer
from x2video_app.state.compare_views import MODES, compose, psnr_db
from x2video_app.state.display import channel_to_u8, checker
from x2video_app.state.live_request import LiveRequest, snapshot_edits

#: what A and B can be, in the order the toolbar lists them
SOURCES = ("channel", "formula", "tier 1", "diffusion", "rendered", "reference", "ground truth")
#: the sources a worker makes, by the tier that makes them
MADE = {"formula": "formula", "tier 1": "residual"}


class Compare(QObject):
    """The Compare toolbar and what it shows; `win` is the main window (its doc, live, render_ctl, viewer, refresh_view)."""

    def __init__(self, win: Any) -> None:
        super().__init__(win)
        self.win, self.doc = win, win.doc
        self.channel = "albedo"  # the intrinsic channel 'channel' shows: the one last viewed
        self.made: dict[tuple[int, int, str], np.ndarray | str] = {}  # (frame, version, tier) -> linear frame, or why not
        self._next_id = 0
        self._inflight: tuple[int, int, str] | None = None  # what the worker is making
        self.worker = LivePreviewer(self)
        self.worker.sigResult.connect(self._made)
        self.psnr: dict[str, float] = {}  # source -> dB against the ground truth, frame on screen (last refresh)
        tb = win.addToolBar("Compare")
        tb.setObjectName("Compare")
        self.mode = self._combo(MODES, "How A and B show: a wipe (A left), side by side, or their difference in false colour")
        self.a = self._combo(SOURCES, "A: the left side of the wipe")
        self.b = self._combo(SOURCES, "B: the right side of the wipe")
        self.a.setCurrentIndex(SOURCES.index("formula"))
        self.b.setCurrentIndex(SOURCES.index("rendered"))
        for c in (self.mode, self.a, self.b):
            c.currentIndexChanged.connect(lambda _i: self.refresh())
        self.at = QSlider(Qt.Orientation.Horizontal)
        self.at.setRange(0, 100)
        self.at.setValue(50)
        self.at.setFixedWidth(120)
        self.at.setToolTip("Where the wipe splits the frame")
        self.at.valueChanged.connect(lambda _v: self.refresh())
        for text, w in (("Compare", self.mode), ("A", self.a), ("B", self.b), ("", self.at)):
            if text:
                tb.addWidget(QLabel(f" {text} "))
            tb.addWidget(w)
        self.toolbar = tb
        self.label = QLabel(win.viewer)  # what A and B are, over the view (a viewport's children scroll with the image)
        self.label.hide()
        self.psnr_label = QLabel()
        self.psnr_label.setToolTip("PSNR of the frame on screen against the shot's ground truth (its rgb channel), display-referred")
        win.statusBar().addPermanentWidget(self.psnr_label)
        self.doc.view_changed.connect(self._view_changed)
        self.doc.shot_changed.connect(self._shot_changed)
        win.live.sigShown.connect(lambda _res: self.refresh())

    def _combo(self, items, tip: str) -> QComboBox:
        c = QComboBox()
        for it in items:
            c.addItem(it, it)
        c.setToolTip(tip)
        return c

    @property
    def active(self) -> bool:
        return self.mode.currentData() != "off" and self.doc.shot is not None

    def refresh(self) -> None:
        self.win.refresh_view()

    def _view_changed(self, view: str) -> None:
        if view in INTRINSIC:
            self.channel = view

    def _shot_changed(self) -> None:
        self.made.clear()

    # -- the sources -------------------------------------------------------------
    def source(self, name: str) -> tuple[np.ndarray | None, str]:
        """(display-referred float32 (H, W, 3) of `name` for the frame on screen, or None; what it is, or why not)."""
        doc, t = self.doc, self.doc.frame
        if name == "channel":
            return channel_to_u8(self.channel, doc.conditioning(t).channels.get(self.channel), doc.size) / 255.0, f"edited {self.channel}"
        if name in MADE:
            return self._made_frame(MADE[name], name)
        if name == "diffusion":
            from x2video.tiers.registry import generative  # the tier that makes the generated version

            live = doc.live
            if live is not None and live.t == t and generative(live.frame.tier):
                return tonemap(live.image), "diffusion (live, this frame's window)"
            img = doc.render.frames.get(t)
            if generative(doc.render.tier) and img is not None:
                return tonemap(img.astype(np.float32)), "diffusion (the last render)"
            return None, "diffusion: render with it first (a local prompt, a reference, or quality 'diffusion')"
        if name == "rendered":
            live = doc.live
            if live is not None and live.t == t:
                return tonemap(live.image), f"rendered (live, {live.frame.tier})"
            img = doc.render.image(t)
            return (None, "rendered: not rendered yet") if img is None else (tonemap(img.astype(np.float32)), f"rendered ({doc.render.tier or 'preview'})")
        if name == "reference":
            ref = doc.reference_image()
            return (None, "reference: none set") if ref is None else (tonemap(ref), "reference")
        if name == "ground truth":
            if doc.shot is None or not doc.shot.has("rgb"):
                return None, "ground truth: this shot has none (no rgb channel)"
            if not doc.shot.has_rgb(t):  # a keyframe shot: Cycles rendered some frames only
                return None, f"ground truth: frame {t} has none (a frame between the shot's keyframes)"
            cycles = str(doc.shot.info.extra.get("renderer", "")).startswith("Cycles")  # the path-traced demo's, a Cycles data set's
            # in the exposure the renders are in: the loader scaled the irradiance by irradiance_scale, not the rgb
            truth = doc.shot.channel("rgb", t).astype(np.float32) * np.float32(doc.shot.info.irradiance_scale)
            return tonemap(truth), "ground truth (Cycles)" if cycles else "ground truth"
        raise ValueError(f"unknown compare source {name!r}; one of {SOURCES}")

    def _made_frame(self, tier: str, name: str) -> tuple[np.ndarray | None, str]:
        doc = self.doc
        key = (doc.frame, doc.version, tier)
        got = self.made.get(key)
        if isinstance(got, np.ndarray):
            return tonemap(got), name
        if isinstance(got, str):
            return None, f"{name}: {got}"
        model = getattr(self.win.render_ctl.renderer, "model", None)
        if model is None:  # the tier modules import torch: not before the model build did
            return None, f"{name}: once the model is loaded"
        if self._inflight is None:  # one at a time (the worker is latest-wins): the next when this one is made
            from x2video.render.live import LiveChoice
            from x2video.tiers.base import TierChoice

            self._next_id += 1
            self._inflight = key
            # each tier's own frame, from the channels: what Compare sets beside the shot's path-traced frames (over the
            # base, a tier would return them where no edit reaches)
            settings = self.win.render_ctl.settings(**{**self.win.render_panel.values(), "base": "off"})
            self.worker.submit(LiveRequest(self._next_id, doc.frame, doc.version, False, doc.shot, snapshot_edits(doc.edits), settings,
                                           model, LiveChoice(TierChoice(tier, "compare view"), None), time.perf_counter()))
        return None, f"{name}: rendering…"

    def _made(self, res) -> None:
        key = (res.request.t, res.request.version, res.choice.preview.tier)
        self._inflight = None
        if len(self.made) > 32:
            self.made.clear()
        if res.frame is not None or res.error != "cancelled":
            self.made[key] = res.image if res.frame is not None else res.error
        if self.active:  # shows it, or asks for the next source still missing
            self.refresh()

    # -- what the window shows -------------------------------------------------------
    def image_or(self, view: Callable[[], np.ndarray]) -> np.ndarray:
        """The compare view while a mode is on, else `view()` (the window's own); updates the PSNR and the labels."""
        out = self._compare() if self.active else None
        if out is None:
            self.label.hide()
            out = view()
        self._update_psnr()
        return out

    def _compare(self) -> np.ndarray | None:
        (a, what_a), (b, what_b) = self.source(self.a.currentData()), self.source(self.b.currentData())
        mode = self.mode.currentData()
        size = self.doc.size
        grey = checker(size) / 255.0
        img = compose(mode, grey if a is None else a, grey if b is None else b, self.at.value() / 100.0)
        sep = " − " if mode == "difference" else " | "
        self.label.setText(f"A: {what_a}{sep}B: {what_b}" + ("  (black: equal, yellow: ≥ 0.25)" if mode == "difference" else ""))
        self.label.setStyleSheet("QLabel { background: rgba(20, 20, 24, 200); color: #eee; padding: 2px 6px; }")
        self.label.adjustSize()
        self.label.move(10, max(10, self.win.viewer.height() - self.label.height() - 10))
        self.label.show()
        self.label.raise_()
        return img

    def _update_psnr(self) -> None:
        self.psnr = {}
        doc = self.doc
        if doc.shot is None or not doc.shot.has("rgb"):
            self.psnr_label.setText("")
            return
        truth, _ = self.source("ground truth")
        if truth is None:  # a frame between a keyframe shot's keyframes
            self.psnr_label.setText("")
            return
        names = ["rendered"] + ([self.a.currentData(), self.b.currentData()] if self.active else [])
        for name in dict.fromkeys(names):
            if name in ("ground truth", "channel"):
                continue
            img, _ = self.source(name) if name not in MADE or self.active else (None, "")
            if img is not None:
                db = psnr_db(img, truth)
                if db is not None:
                    self.psnr[name] = db
        parts = [f"{n} {v:.2f} dB" for n, v in self.psnr.items()]
        self.psnr_label.setText(f"PSNR vs ground truth, frame {doc.frame}: " + (", ".join(parts) if parts else "nothing rendered yet"))

    def shutdown(self) -> None:
        self.worker.shutdown()
