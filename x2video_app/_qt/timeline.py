"""Timeline: a scrubber that marks keyframes, the level each rendered frame came from, the formula's preview
frames still waiting for the network, and the window in flight."""
from __future__ import annotations

from PySide6.QtCore import QPointF, QRectF, QSize, Qt, QTimer, Signal
from PySide6.QtGui import QBrush, QColor, QFont, QPainter, QPen, QPolygonF
from PySide6.QtWidgets import QHBoxLayout, QLabel, QSpinBox, QStyle, QToolButton, QWidget

#: colour of a rendered frame by level; the top level (keyframes) is gold, lower levels cooler
LEVEL_COLOURS = [QColor(255, 196, 0), QColor(64, 170, 255), QColor(90, 210, 140), QColor(200, 120, 255), QColor(255, 120, 120)]
#: level 0: a frame from a per-frame tier (formula or tier-1 network: no windows, no levels)
PER_FRAME_COLOUR = QColor(0, 200, 200)
#: the formula's preview of a frame the render has not delivered yet (hatched)
PREVIEW_COLOUR = QColor(150, 150, 160)
#: the shot's path-traced keyframes (a keyframe shot, or the keyframes setting): diamonds above the cells
PATH_TRACED_KEY_COLOUR = QColor(235, 235, 245)
#: the strip under the cells: where each frame comes from and which tier edited it (`x2video_app.state.frame_sources.KINDS`)
STRIP_COLOURS = {"path-traced": QColor(225, 225, 232), "filled": QColor(120, 150, 200), "rendered": QColor(110, 110, 120),
                 "formula": QColor(90, 210, 140), "formula+residual": QColor(255, 150, 60), "residual": QColor(255, 150, 60),
                 "generated": QColor(220, 90, 220)}


def level_colour(level: int, top: int) -> QColor:
    """Colour of `level` when `top` is the keyframe level (so keyframes always look the same); level 0 is a per-frame tier."""
    if level <= 0:
        return PER_FRAME_COLOUR
    return LEVEL_COLOURS[max(0, top - level) % len(LEVEL_COLOURS)]


class TimelineBar(QWidget):
    """The painted strip: one cell per frame. Click or drag to scrub (sigFrame)."""

    sigFrame = Signal(int)

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.num_frames = 1
        self.current = 0
        self.keyframes: set[int] = set()
        self.levels: dict[int, int] = {}  # rendered frame -> level
        self.top_level = 1
        self.in_flight: list[int] = []
        self.preview: set[int] = set()  # frames showing the formula's preview
        self.marks: set[int] = set()  # the shot's path-traced keyframes
        self.kinds: dict[int, str] = {}  # frame -> its strip's kind (STRIP_COLOURS)
        self.setMinimumHeight(46)
        self.setMouseTracking(False)
        self.setToolTip("Timeline: click or drag to scrub. Gold triangles mark the render's keyframes, white diamonds the shot's "
                        "path-traced keyframes; cell colour is the level a frame was rendered at (cyan: one pass per frame); "
                        "hatched grey: the formula's preview, until the network's frame arrives.\nThe strip below: white "
                        "path-traced, blue filled from the keyframes, grey rendered from the channels; edited over the base by "
                        "green the formula, orange formula+residual, magenta generated.")

    def sizeHint(self) -> QSize:
        return QSize(600, 46)

    def set_state(self, num_frames: int, keyframes, levels: dict[int, int], top_level: int, in_flight=(), preview=(),
                  marks=(), kinds: dict[int, str] | None = None) -> None:
        """`marks`: the shot's path-traced keyframes; `kinds`: frame -> where it comes from / which tier edited it."""
        self.num_frames = max(1, num_frames)
        self.marks = set(marks)
        self.kinds = dict(kinds or {})
        self.preview = set(preview)
        self.keyframes = set(keyframes)
        self.levels = dict(levels)
        self.top_level = max(1, top_level)
        self.in_flight = list(in_flight)
        self.update()

    def set_current(self, t: int) -> None:
        self.current = t
        self.update()

    def _x(self, t: float) -> float:
        return 6 + (self.width() - 12) * t / self.num_frames

    def _frame_at(self, x: float) -> int:
        t = int((x - 6) / max(1.0, self.width() - 12) * self.num_frames)
        return max(0, min(self.num_frames - 1, t))

    def paintEvent(self, ev) -> None:
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing, True)
        h = self.height()
        top, bot = 14, h - 14
        p.fillRect(self.rect(), QColor(36, 36, 40))
        p.fillRect(QRectF(self._x(0), top, self._x(self.num_frames) - self._x(0), bot - top), QColor(58, 58, 64))
        for t in self.in_flight:
            p.fillRect(QRectF(self._x(t), top, max(1.0, self._x(t + 1) - self._x(t)), bot - top), QColor(255, 255, 255, 60))
        for t in self.preview:
            x0, x1 = self._x(t), self._x(t + 1)
            p.fillRect(QRectF(x0, top + 3, max(1.0, x1 - x0 - (1 if x1 - x0 > 3 else 0)), bot - top - 6), QBrush(PREVIEW_COLOUR, Qt.BrushStyle.BDiagPattern))
        for t, lvl in self.levels.items():
            x0, x1 = self._x(t), self._x(t + 1)
            p.fillRect(QRectF(x0, top + 3, max(1.0, x1 - x0 - (1 if x1 - x0 > 3 else 0)), bot - top - 6), level_colour(lvl, self.top_level))
        for t, kind in self.kinds.items():
            x0, x1 = self._x(t), self._x(t + 1)
            p.fillRect(QRectF(x0, bot, max(1.0, x1 - x0 - (1 if x1 - x0 > 3 else 0)), 3), STRIP_COLOURS.get(kind, PREVIEW_COLOUR))
        p.setPen(Qt.PenStyle.NoPen)
        p.setBrush(PATH_TRACED_KEY_COLOUR)
        for t in self.marks:
            xc = (self._x(t) + self._x(t + 1)) / 2
            p.drawPolygon(QPolygonF([QPointF(xc, top - 9), QPointF(xc + 4, top - 5), QPointF(xc, top - 1), QPointF(xc - 4, top - 5)]))
        p.setBrush(QColor(255, 196, 0))
        for t in self.keyframes:
            xc = (self._x(t) + self._x(t + 1)) / 2
            p.drawPolygon(QPolygonF([QPointF(xc - 5, 2), QPointF(xc + 5, 2), QPointF(xc, top - 1)]))
        # tick labels every ~10% of the shot
        p.setPen(QColor(200, 200, 205))
        f = QFont(self.font())
        f.setPointSizeF(max(7.0, f.pointSizeF() - 1.5))
        p.setFont(f)
        step = max(1, round(self.num_frames / 10))
        for t in range(0, self.num_frames, step):
            p.drawText(QPointF(self._x(t) + 1, h - 2), str(t))
        xc = (self._x(self.current) + self._x(self.current + 1)) / 2
        p.setPen(QPen(QColor(255, 80, 80), 2))
        p.drawLine(QPointF(xc, 0), QPointF(xc, h))
        p.end()

    def mousePressEvent(self, ev) -> None:
        self.sigFrame.emit(self._frame_at(ev.position().x()))

    def mouseMoveEvent(self, ev) -> None:
        if ev.buttons() & Qt.MouseButton.LeftButton:
            self.sigFrame.emit(self._frame_at(ev.position().x()))


class Timeline(QWidget):
    """Play button, frame number and the bar; plays at the shot's fps. sigFrame(t) when the user moves."""

    sigFrame = Signal(int)

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.play_button = QToolButton()
        self.play_button.setIcon(self.style().standardIcon(QStyle.StandardPixmap.SP_MediaPlay))
        self.play_button.setCheckable(True)
        self.play_button.setToolTip("Play / pause (Space)")
        self.frame_box = QSpinBox()
        self.frame_box.setToolTip("Current frame")
        self.frame_box.setMinimumWidth(64)
        self.count_label = QLabel("/ 0")
        self.count_label.setMinimumWidth(self.count_label.fontMetrics().horizontalAdvance("/ 00000"))
        self.bar = TimelineBar()
        lay = QHBoxLayout(self)
        lay.setContentsMargins(4, 2, 4, 2)
        lay.addWidget(self.play_button)
        lay.addWidget(QLabel("Frame"))
        lay.addWidget(self.frame_box)
        lay.addWidget(self.count_label)
        lay.addWidget(self.bar, 1)
        self._timer = QTimer(self)
        self._timer.timeout.connect(self._advance)
        self.play_button.toggled.connect(self._toggle_play)
        self.frame_box.valueChanged.connect(self.sigFrame.emit)
        self.bar.sigFrame.connect(self.sigFrame.emit)
        self.fps = 10.0

    def set_num_frames(self, n: int, fps: float) -> None:
        self.fps = fps if fps > 0 else 10.0
        self.frame_box.blockSignals(True)
        self.frame_box.setRange(0, max(0, n - 1))
        self.frame_box.blockSignals(False)
        self.count_label.setText(f"/ {n - 1}")
        self.bar.num_frames = max(1, n)
        self.bar.update()

    def set_current(self, t: int) -> None:
        self.frame_box.blockSignals(True)
        self.frame_box.setValue(t)
        self.frame_box.blockSignals(False)
        self.bar.set_current(t)

    def _toggle_play(self, on: bool) -> None:
        self.play_button.setIcon(self.style().standardIcon(QStyle.StandardPixmap.SP_MediaPause if on else QStyle.StandardPixmap.SP_MediaPlay))
        if on:
            self._timer.start(int(1000 / self.fps))
        else:
            self._timer.stop()

    def stop(self) -> None:
        self.play_button.setChecked(False)

    def _advance(self) -> None:
        n = self.bar.num_frames
        self.sigFrame.emit((self.frame_box.value() + 1) % n)
