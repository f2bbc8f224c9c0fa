"""Render settings (quality tier, preset, seed, window N, scheme, seam pass, noise shared across frames, exposure, device),
Render/Cancel, a progress bar per level and the ETA.

The panel's rows sit in a scroll area and are never squeezed below their size: when the progress bars or a longer
status appear, the panel asks its dock for the room (taken from the dock below it); what the window cannot give
scrolls."""
from __future__ import annotations

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDockWidget,
    QDoubleSpinBox,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QMainWindow,
    QProgressBar,
    QPushButton,
    QScrollArea,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from x2video.render.settings import RenderSettings
from x2video_app.state.render_state import RenderState

#: the Quality choices (RenderSettings.quality): (value, label, tooltip)
QUALITY_ITEMS = (
    ("auto", "auto", "The tier-1 network where nothing must be generated, the diffusion sampler where something must "
                     "(a dropped channel or a reference: whole frames; a masked A|M|R region or a local prompt: inside its mask, "
                     "tier 1 around it); the status bar says which ran and why."),
    ("formula", "formula (no network)", "Albedo x irradiance of the edited channels: exact for diffuse light, instant, no weights."),
    ("residual", "residual (tier 1)", "One pass of the tier-1 network per frame over the formula: glossy light, metals, "
                                      "emitters. Fast, cannot flicker; generates nothing."),
    ("diffusion", "diffusion", "The video diffusion sampler (keyframes, then interpolation levels): generates what is "
                               "missing or masked, follows prompts and a reference."),
)
NO_RESIDUAL = "The loaded model has no tier-1 network (residual.safetensors beside its weights)."
#: progress bars the panel keeps room for before a render starts (keyframes and two levels: the recursive scheme up to
#: 65 frames), so the first render does not change its height
RESERVED_BARS = 3
#: lines of status text kept free (the progress line, the tier and why, the first keyframe)
RESERVED_STATUS_LINES = 5


class RenderPanel(QWidget):
    """Emits sigRender / sigCancel; `show_state(render_state)` refreshes the progress display."""

    sigRender = Signal()
    sigCancel = Signal()
    sigSettingsChanged = Signal()
    sigDevice = Signal(str)  # "auto" | "cpu" | "cuda"

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.quality = QComboBox()
        for value, label, tip in QUALITY_ITEMS:
            self.quality.addItem(label, value)
            self.quality.setItemData(self.quality.count() - 1, tip, Qt.ItemDataRole.ToolTipRole)
        self.quality.setToolTip("Which tier renders (RenderSettings.quality). Whatever runs, the formula's frames show at "
                                "once and the network's replace them as they arrive.")
        self.preset = QComboBox()
        self.preset.addItem("fast", "fast")
        self.preset.addItem("quality (DDIM-20)", "quality")
        self.preset.setToolTip("fast: LCM-2 when distilled weights are loaded, else DDIM-4. quality: DDIM-20.")
        self.seed = QSpinBox()
        self.seed.setRange(0, 2**31 - 1)
        self.seed.setToolTip("Seed of the initial noise: same inputs and seed give the same frames")
        self.window = QSpinBox()
        self.window.setRange(2, 17)
        self.window.setValue(5)
        self.window.setToolTip("Frames per window N (the model was trained with N=5)")
        self.scheme = QComboBox()
        self.scheme.addItem("recursive (keyframes first)", "recursive")
        self.scheme.addItem("sequential (baseline)", "sequential")
        self.seams = QCheckBox("Seam pass")
        self.seams.setChecked(RenderSettings.seams)
        self.seams.setToolTip("Recursive, 18 frames or more at N=5: make each keyframe again with its neighbours after the "
                              "first interpolation level. Steadier where the model generates (a channel missing or masked), "
                              "slightly less faithful to a reference frame; about 1.2x the windows on 65 frames.")
        self.levels = QSpinBox()
        self.levels.setRange(0, 8)
        self.levels.setSpecialValueText("auto")  # 0: as many levels as the shot needs (RenderSettings.max_levels None)
        self.levels.setToolTip("Recursive: at most this many levels K. auto: the fewest that let one keyframe window span "
                               "the shot (K=3 at 65 frames, keyframes 16 apart, as in the paper). Fewer put the keyframes "
                               "(N-1)^(K-1) frames apart in chained keyframe windows.")
        self.scheme.currentIndexChanged.connect(lambda _i: self.seams.setEnabled(self.scheme.currentData() == "recursive"))
        self.scheme.currentIndexChanged.connect(lambda _i: self.levels.setEnabled(self.scheme.currentData() == "recursive"))
        self.noise_shared = QDoubleSpinBox()
        self.noise_shared.setRange(0.0, 1.0)
        self.noise_shared.setSingleStep(0.05)
        self.noise_shared.setDecimals(2)
        self.noise_shared.setValue(RenderSettings.noise_shared)
        self.noise_shared.setToolTip("Fraction of the noise every frame shares (each frame keeps its own noise in every "
                                     "window). Higher: less flicker; 0: independent noise per frame. Default "
                                     f"{RenderSettings.noise_shared:g}: a quarter less flicker with all channels at the same "
                                     "accuracy; 40-60 % less where a channel is missing or masked, about 1 dB less accurate "
                                     "there (model card).")
        self.exposure_auto = QCheckBox("auto")
        self.exposure_auto.setChecked(True)
        self.exposure_auto.setToolTip("MP4 exposure = the shot's own irradiance normalisation (what the model saw). "
                                      "EXR export is always in the input's units.")
        self.exposure = QDoubleSpinBox()
        self.exposure.setRange(-16.0, 16.0)
        self.exposure.setSingleStep(0.5)
        self.exposure.setSuffix(" stops")
        self.exposure.setEnabled(False)
        self.exposure.setToolTip("MP4 exposure in stops on the input's units (0: as the input's radiance is)")
        self.exposure_auto.toggled.connect(lambda on: self.exposure.setEnabled(not on))
        exposure_row = QHBoxLayout()
        exposure_row.addWidget(self.exposure_auto)
        exposure_row.addWidget(self.exposure, 1)
        self.device = QComboBox()
        self.device.setToolTip("Where the model runs. auto: CUDA when torch sees a GPU, else the CPU.")
        self.set_devices(cuda=False)
        form = QFormLayout()
        form.addRow("Quality", self.quality)
        form.addRow("Preset", self.preset)
        form.addRow("Seed", self.seed)
        form.addRow("Window N", self.window)
        form.addRow("Scheme", self.scheme)
        form.addRow("", self.seams)
        form.addRow("Max levels", self.levels)
        form.addRow("Noise shared", self.noise_shared)
        form.addRow("Exposure", exposure_row)
        form.addRow("Device", self.device)
        self.noise_shared.valueChanged.connect(lambda _v: self.sigSettingsChanged.emit())
        self.seams.toggled.connect(lambda _on: self.sigSettingsChanged.emit())
        self.exposure_auto.toggled.connect(lambda _on: self.sigSettingsChanged.emit())
        self.exposure.valueChanged.connect(lambda _v: self.sigSettingsChanged.emit())
        self.device.currentIndexChanged.connect(lambda _i: self.sigDevice.emit(self.device.currentData()))
        for w in (self.quality, self.preset, self.scheme):
            w.currentIndexChanged.connect(lambda _i: self.sigSettingsChanged.emit())
        for w in (self.seed, self.window, self.levels):
            w.valueChanged.connect(lambda _v: self.sigSettingsChanged.emit())

        self.render_button = QPushButton("Render")
        self.render_button.setToolTip("Render the shot with the current edits (Ctrl+R)")
        self.render_button.setStyleSheet("QPushButton { font-weight: bold; padding: 4px 14px; }")
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setEnabled(False)
        self.cancel_button.setToolTip("Stop after the current denoising step; finished frames are kept")
        self.render_button.clicked.connect(self.sigRender.emit)
        self.cancel_button.clicked.connect(self.sigCancel.emit)
        buttons = QHBoxLayout()
        buttons.addWidget(self.render_button)
        buttons.addWidget(self.cancel_button)

        self.model_label = QLabel()
        self.base_check = QCheckBox()  # the shot's path-traced frames as the base (`set_base`; RenderSettings.base)
        self.base_check.setChecked(RenderSettings.base == "auto")
        self.base_check.setToolTip("Where the shot carries its own path-traced frames, a render keeps them: frames no edit "
                                   "reaches come back bit for bit, edits render as differences over them, frames between "
                                   "keyframes are filled from them. Off: every frame re-rendered from the channels "
                                   "(x2video render --base off), to compare.")
        self.base_check.setVisible(False)
        self.base_check.toggled.connect(lambda _on: self.sigSettingsChanged.emit())
        self.status_label = QLabel("Ready")
        self.status_label.setWordWrap(True)
        self.status_label.setAlignment(Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignTop)
        self.status_label.setMinimumHeight(RESERVED_STATUS_LINES * self.status_label.fontMetrics().lineSpacing() + 4)
        self.bars_box = QGroupBox("Progress per level")
        self.bars_layout = QVBoxLayout(self.bars_box)
        self.bars_layout.setContentsMargins(6, 4, 6, 4)
        self.bars_layout.setAlignment(Qt.AlignmentFlag.AlignTop)
        self._bars: dict[int, QProgressBar] = {}
        self._empty = QLabel("No render yet")
        self.bars_layout.addWidget(self._empty)
        self.bars_box.setMinimumHeight(self._bars_height(RESERVED_BARS))

        self.body = QWidget()
        lay = QVBoxLayout(self.body)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.addLayout(form)
        lay.addLayout(buttons)
        lay.addWidget(self.model_label)
        lay.addWidget(self.base_check)
        lay.addWidget(self.bars_box)
        lay.addWidget(self.status_label)
        lay.addStretch(1)
        self.scroll = QScrollArea()
        self.scroll.setWidget(self.body)
        self.scroll.setWidgetResizable(True)
        self.scroll.setFrameShape(QScrollArea.Shape.NoFrame)
        self.scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        outer = QVBoxLayout(self)
        outer.setContentsMargins(0, 0, 0, 0)
        outer.addWidget(self.scroll)
        self._room_timer = QTimer(self)
        self._room_timer.setSingleShot(True)
        self._room_timer.timeout.connect(self.claim_room)

    def _bars_height(self, n: int) -> int:
        """The progress box's height with `n` bars in it."""
        m = self.bars_layout.contentsMargins()
        bar = QProgressBar().sizeHint().height()
        title = self.bars_box.fontMetrics().lineSpacing() + 6
        return title + m.top() + m.bottom() + n * bar + max(n - 1, 0) * self.bars_layout.spacing()

    def sizeHint(self):  # noqa: N802 (Qt)
        """The rows' own size (QScrollArea's hint is capped), so a dock starts tall enough for them."""
        hint = self.body.sizeHint()
        return hint.expandedTo(self.body.minimumSizeHint()).grownBy(self.scroll.contentsMargins())

    def needed_height(self) -> int:
        """The height the rows take at the panel's current width."""
        w = self.scroll.viewport().width()
        h = self.body.heightForWidth(w) if self.body.hasHeightForWidth() else -1
        return max(h, self.body.minimumSizeHint().height())

    def claim_room(self) -> None:
        """Grow the panel's dock to the rows' height, taking the room from the docks above and below it (down to their
        minimum); what the window cannot give scrolls. Nothing when the panel is not docked in a main window."""
        dock = self.parentWidget()
        win = dock.parentWidget() if isinstance(dock, QDockWidget) else None
        if not isinstance(win, QMainWindow) or dock.isFloating() or not self.isVisible():
            return
        missing = self.needed_height() - self.scroll.viewport().height()
        if missing <= 0:
            return
        area = win.dockWidgetArea(dock)
        column = [d for d in win.findChildren(QDockWidget) if d is not dock and d.isVisible() and not d.isFloating()
                  and win.dockWidgetArea(d) == area and d.x() == dock.x()]
        heights = []
        for d in column:  # resizeDocks with this dock alone moves the splitter part of the way: give each its height
            give = max(0, min(missing, d.height() - d.minimumSizeHint().height()))
            heights.append(d.height() - give)
            missing -= give
        grown = dock.height() + sum(d.height() for d in column) - sum(heights)
        if column and grown > dock.height():
            win.resizeDocks([dock, *column], [grown, *heights], Qt.Orientation.Vertical)

    def showEvent(self, ev) -> None:  # noqa: N802 (Qt)
        super().showEvent(ev)
        self._room_timer.start(0)

    def values(self) -> dict:
        return {
            "preset": self.preset.currentData(),
            "seed": self.seed.value(),
            "window": self.window.value(),
            "scheme": self.scheme.currentData(),
            "seams": self.seams.isChecked() and self.scheme.currentData() == "recursive",
            "noise_shared": self.noise_shared.value(),
            "max_levels": self.levels.value() or None if self.scheme.currentData() == "recursive" else None,
            "exposure": "auto" if self.exposure_auto.isChecked() else float(self.exposure.value()),
            "quality": self.quality.currentData(),
            "base": "auto" if self.base_check.isChecked() else "off",
        }

    def set_base(self, caption: str) -> None:
        """Say what a render keeps as its base (`Document.base_caption`), with a box to turn it off; '' (a shot without
        path-traced frames) hides it."""
        self.base_check.setText(caption)
        self.base_check.setVisible(bool(caption))

    def set_residual_available(self, available: bool | None) -> None:
        """Grey out quality 'residual' unless the model has the tier-1 network (`set_tier_available`). None: no
        model yet, so nothing to say."""
        self.set_tier_available("residual", NO_RESIDUAL if available is False else None)

    def set_tier_available(self, tier: str, reason: str | None) -> None:
        """Grey out the quality `tier` with `reason` as its tooltip (None: offer it again); a selected one that
        cannot run falls back to auto."""
        i = self.quality.findData(tier)
        self.quality.model().item(i).setEnabled(reason is None)
        self.quality.setItemData(i, QUALITY_ITEMS[i][2] if reason is None else reason, Qt.ItemDataRole.ToolTipRole)
        if reason is not None and self.quality.currentIndex() == i:
            self.quality.setCurrentIndex(self.quality.findData("auto"))

    def set_devices(self, cuda: bool) -> None:
        """Offer auto and cpu, and cuda where torch sees a GPU; keeps the current choice where it can."""
        current = self.device.currentData() or "auto"
        self.device.blockSignals(True)
        self.device.clear()
        self.device.addItem(f"auto ({'cuda' if cuda else 'cpu'})", "auto")
        self.device.addItem("cpu", "cpu")
        if cuda:
            self.device.addItem("cuda", "cuda")
        i = self.device.findData(current)
        self.device.setCurrentIndex(max(i, 0))
        self.device.blockSignals(False)

    def set_running(self, running: bool) -> None:
        self.render_button.setEnabled(not running)
        self.cancel_button.setEnabled(running)

    def _ensure_bars(self, progress: list[tuple[int, int, int]], top: int) -> None:
        levels = [lv for lv, _, _ in progress]
        if list(self._bars) == levels:
            return
        for b in self._bars.values():
            self.bars_layout.removeWidget(b)
            b.deleteLater()
        self._bars = {}
        self._empty.setVisible(not levels)
        for lv in levels:
            b = QProgressBar()
            b.setTextVisible(True)
            self._bars[lv] = b
            self.bars_layout.addWidget(b)
        self.bars_box.setMinimumHeight(self._bars_height(max(len(levels), RESERVED_BARS)))
        self._room_timer.start(0)

    def show_state(self, st: RenderState) -> None:
        progress = st.level_progress()
        top = st.top_level
        self._ensure_bars(progress, top)
        unit = "frames" if st.per_frame else "windows"
        for lv, done, planned in progress:
            b = self._bars[lv]
            if st.per_frame:
                name = f"{st.tier} frames"
            else:
                name = "keyframes" if lv == top and st.level_order and len(st.level_order) > 1 else (f"level {lv}" if len(st.level_order) > 1 else "windows")
            b.setMaximum(max(planned, done, 1) if planned else 0)  # 0 = busy indicator when the plan is unknown
            if planned:
                b.setValue(done)
            b.setFormat(f"{name}: {done}/{planned} {unit}" if planned else f"{name}: {done} {unit}")
        eta = st.eta_seconds()
        if st.status == "running":
            msg = f"Rendering: {len(st.frames)}/{st.num_frames or '?'} frames"
            if st.preview:
                msg += f" (+{len(st.preview)} formula previews)"
            if eta is not None:
                msg += f", about {eta:.0f} s left"
        elif st.status == "finished":
            msg = f"Finished {len(st.frames)} frames in {st.finished_at - st.started_at:.1f} s"
        elif st.status == "cancelled":
            msg = f"Cancelled; kept {len(st.frames)} finished frames"
        elif st.status == "failed":
            msg = f"Render failed: {st.error}"
        else:
            msg = "Ready"
        if st.tier:
            msg += f"\nTier: {st.tier}" + (f" ({st.reason})" if st.reason else "")
        ttk = st.time_to_first_keyframe()
        if ttk is not None:
            msg += f"\nFirst {'network frame' if st.per_frame else 'keyframe'} after {ttk:.2f} s"
        if msg != self.status_label.text():
            self.status_label.setText(msg)
            self._room_timer.start(0)  # once the layout has the new text: room for it
