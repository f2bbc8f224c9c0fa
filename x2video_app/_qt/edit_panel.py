"""Parametric edit panel (paper: parametric tuning): albedo colour/tint/HSV, roughness, metallic, irradiance
exposure/tint, for the selected mask or the whole frame. Values are a plain dict (`x2video.edits.NEUTRAL_TUNING`)."""
from __future__ import annotations

from typing import Any

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (
    QCheckBox,
    QColorDialog,
    QComboBox,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QVBoxLayout,
    QWidget,
)
from superqt import QLabeledDoubleSlider

from x2video.edits import NEUTRAL_TUNING

_MODE_RANGES = {"set": (0.0, 1.0, 0.5), "offset": (-1.0, 1.0, 0.0), "scale": (0.0, 2.0, 1.0), "none": (0.0, 1.0, 0.5)}


def colour_css(rgb: tuple[float, float, float]) -> str:
    r, g, b = (int(round(255 * max(0.0, min(1.0, c)))) for c in rgb)
    fg = "#000" if 0.299 * r + 0.587 * g + 0.114 * b > 140 else "#fff"
    return f"QPushButton {{ background: rgb({r},{g},{b}); color: {fg}; border: 1px solid #888; padding: 3px; }}"


class EditPanel(QWidget):
    """sigParam(key, value, final): final=False while a slider is dragged (undo merges these)."""

    sigParam = Signal(str, object, bool)
    sigTarget = Signal(bool)  # True = whole frame (global), False = selected mask
    sigReset = Signal()

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self._params = dict(NEUTRAL_TUNING)
        self._updating = False
        self.target_label = QLabel()
        self.target_label.setWordWrap(True)
        self.global_box = QCheckBox("Edit the whole frame (global)")
        self.global_box.setToolTip("Off: edits apply inside the selected mask only")
        self.global_box.toggled.connect(lambda on: None if self._updating else self.sigTarget.emit(on))

        # albedo
        self.colour_on = QCheckBox("Set colour")
        self.colour_button = QPushButton("pick…")
        self.tint_button = QPushButton("tint…")
        self.hue = self._slider(-180, 180, "hue")
        self.sat = self._slider(0, 2, "saturation")
        self.val = self._slider(0, 2, "value")
        alb = QGroupBox("Albedo")
        f = QFormLayout(alb)
        crow = QHBoxLayout()
        crow.addWidget(self.colour_on)
        crow.addWidget(self.colour_button, 1)
        crow.addWidget(self.tint_button, 1)
        f.addRow(crow)
        f.addRow("Hue°", self.hue)
        f.addRow("Saturation ×", self.sat)
        f.addRow("Value ×", self.val)
        self.colour_on.toggled.connect(self._colour_toggled)
        self.colour_button.clicked.connect(lambda: self._pick("albedo_colour"))
        self.tint_button.clicked.connect(lambda: self._pick("albedo_tint"))

        # roughness / metallic
        mat = QGroupBox("Material")
        fm = QFormLayout(mat)
        self.rough_mode, self.rough = self._mode_row("roughness")
        self.metal_mode, self.metal = self._mode_row("metallic")
        fm.addRow("Roughness", self._pair(self.rough_mode, self.rough))
        fm.addRow("Metallic", self._pair(self.metal_mode, self.metal))

        # light
        light = QGroupBox("Light (irradiance)")
        fl = QFormLayout(light)
        self.exposure = self._slider(-4, 4, "exposure")
        self.light_tint = QPushButton("tint…")
        self.light_tint.clicked.connect(lambda: self._pick("irradiance_tint"))
        fl.addRow("Exposure (stops)", self.exposure)
        fl.addRow("Tint", self.light_tint)

        self.reset_button = QPushButton("Reset these edits")
        self.reset_button.clicked.connect(self.sigReset.emit)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.addWidget(self.target_label)
        lay.addWidget(self.global_box)
        lay.addWidget(alb)
        lay.addWidget(mat)
        lay.addWidget(light)
        lay.addWidget(self.reset_button)
        lay.addStretch(1)
        self.set_params(NEUTRAL_TUNING, "the whole frame", True, True)

    # -- builders --------------------------------------------------------------
    def _slider(self, lo: float, hi: float, key: str) -> QLabeledDoubleSlider:
        s = QLabeledDoubleSlider(Qt.Orientation.Horizontal)
        s.setRange(lo, hi)
        s.setDecimals(2)
        s.setSingleStep((hi - lo) / 100)
        s.valueChanged.connect(lambda v, k=key: None if self._updating else self.sigParam.emit(k, float(v), not s.isSliderDown()))
        s.sliderReleased.connect(lambda k=key: None if self._updating else self.sigParam.emit(k, float(s.value()), True))
        return s

    def _mode_row(self, key: str) -> tuple[QComboBox, QLabeledDoubleSlider]:
        mode = QComboBox()
        for m in ("none", "set", "offset", "scale"):
            mode.addItem(m, m)
        slider = self._slider(0, 1, key)

        def changed(_i: int) -> None:
            if self._updating:
                return
            m = mode.currentData()
            lo, hi, neutral = _MODE_RANGES[m]
            self._updating = True
            slider.setRange(lo, hi)
            slider.setValue(neutral)
            slider.setEnabled(m != "none")
            self._updating = False
            self.sigParam.emit(f"{key}_mode", m, True)

        mode.currentIndexChanged.connect(changed)
        return mode, slider

    @staticmethod
    def _pair(a: QWidget, b: QWidget) -> QWidget:
        w = QWidget()
        h = QHBoxLayout(w)
        h.setContentsMargins(0, 0, 0, 0)
        h.addWidget(a)
        h.addWidget(b, 1)
        return w

    # -- colour ----------------------------------------------------------------
    def _colour_toggled(self, on: bool) -> None:
        if self._updating:
            return
        self.sigParam.emit("albedo_colour", tuple(self._last_colour) if on else None, True)

    def _pick(self, key: str) -> None:
        cur = self._params.get(key) or self._last_colour
        c = QColorDialog.getColor(QColor.fromRgbF(*cur), self, key.replace("_", " "))
        if c.isValid():
            self.sigParam.emit(key, (c.redF(), c.greenF(), c.blueF()), True)

    # -- refresh from the document --------------------------------------------
    def set_params(self, params: dict[str, Any], target_name: str, is_global: bool, can_toggle: bool) -> None:
        self._updating = True
        p = {**NEUTRAL_TUNING, **params}
        self._params = p
        self.target_label.setText(f"Editing: <b>{target_name}</b>")
        self.global_box.setChecked(is_global)
        self.global_box.setEnabled(can_toggle)
        self._last_colour = p["albedo_colour"] or getattr(self, "_last_colour", (0.8, 0.2, 0.2))
        self.colour_on.setChecked(p["albedo_colour"] is not None)
        self.colour_button.setStyleSheet(colour_css(self._last_colour))
        self.tint_button.setStyleSheet(colour_css(p["albedo_tint"]))
        self.light_tint.setStyleSheet(colour_css(p["irradiance_tint"]))
        self.hue.setValue(p["hue"])
        self.sat.setValue(p["saturation"])
        self.val.setValue(p["value"])
        self.exposure.setValue(p["exposure"])
        for key, mode, slider in (("roughness", self.rough_mode, self.rough), ("metallic", self.metal_mode, self.metal)):
            m = p[f"{key}_mode"]
            mode.setCurrentIndex(mode.findData(m))
            lo, hi, _ = _MODE_RANGES[m]
            slider.setRange(lo, hi)
            slider.setValue(p[key])
            slider.setEnabled(m != "none")
        self._updating = False

    def params(self) -> dict[str, Any]:
        return dict(self._params)
