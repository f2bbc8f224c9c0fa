"""The image viewer: zoom (wheel), pan (middle/right drag or the pan tool), brush/eraser strokes and id picking."""
from __future__ import annotations

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt, Signal
from PySide6.QtGui import QBrush, QColor, QImage, QPainter, QPen, QPixmap
from PySide6.QtWidgets import QGraphicsEllipseItem, QGraphicsPixmapItem, QGraphicsScene, QGraphicsView

TOOLS = ("pan", "brush", "eraser", "fill")


def qimage_from_u8(rgb: np.ndarray) -> QImage:
    """uint8 (H, W, 3) -> QImage that owns a copy of the pixels."""
    rgb = np.ascontiguousarray(rgb)
    h, w = rgb.shape[:2]
    return QImage(rgb.data, w, h, 3 * w, QImage.Format.Format_RGB888).copy()


class Viewer(QGraphicsView):
    """Shows one uint8 image; tools turn mouse input into image-space signals.

    Signals carry image pixel coordinates (x right, y down, floats):
    sigStrokePoint(x, y, starting) while the brush/eraser is dragged, sigStrokeEnd() on release,
    sigPick(x, y) for the fill tool, sigHover(x, y) for the status bar.
    """

    sigStrokePoint = Signal(float, float, bool)
    sigStrokeEnd = Signal()
    sigPick = Signal(float, float)
    sigHover = Signal(float, float)

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.setScene(QGraphicsScene(self))
        self.setBackgroundBrush(QBrush(QColor(24, 24, 27)))
        self.setRenderHint(QPainter.RenderHint.SmoothPixmapTransform, False)
        self.setTransformationAnchor(QGraphicsView.ViewportAnchor.AnchorUnderMouse)
        self.setResizeAnchor(QGraphicsView.ViewportAnchor.AnchorViewCenter)
        self.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAsNeeded)
        self.setMouseTracking(True)
        self.setMinimumSize(320, 224)
        self._pix = QGraphicsPixmapItem()
        self.scene().addItem(self._pix)
        self._cursor = QGraphicsEllipseItem()
        self._cursor.setPen(QPen(QColor(255, 255, 255, 200), 0))
        self._cursor.setZValue(10)
        self._cursor.setVisible(False)
        self.scene().addItem(self._cursor)
        self._tool = "brush"
        self._brush_radius = 8.0
        self._stroking = False
        self._panning: QPointF | None = None
        self._fitted = False
        self._image_size: tuple[int, int] | None = None

    # -- content ---------------------------------------------------------------
    def set_image(self, rgb: np.ndarray) -> None:
        """Show a uint8 (H, W, 3) image; keeps the current zoom unless the size changed."""
        size = (rgb.shape[0], rgb.shape[1])
        self._pix.setPixmap(QPixmap.fromImage(qimage_from_u8(rgb)))
        self.scene().setSceneRect(QRectF(0, 0, size[1], size[0]))
        if size != self._image_size:
            self._image_size = size
            self.fit()

    def image(self) -> QImage:
        return self._pix.pixmap().toImage()

    def fit(self) -> None:
        """Zoom so the whole image is visible."""
        self.fitInView(self.scene().sceneRect(), Qt.AspectRatioMode.KeepAspectRatio)
        self._fitted = True
        self._update_smoothing()

    def zoom(self, factor: float) -> None:
        cur = self.transform().m11()
        factor = max(0.05 / cur, min(factor, 64.0 / cur))
        self.scale(factor, factor)
        self._fitted = False
        self._update_smoothing()

    def _update_smoothing(self) -> None:
        # smooth when the image is shown near its size; sharp pixels when zoomed in to paint
        self._pix.setTransformationMode(
            Qt.TransformationMode.SmoothTransformation if self.zoom_level < 3.0 else Qt.TransformationMode.FastTransformation
        )

    @property
    def zoom_level(self) -> float:
        return self.transform().m11()

    # -- tools -----------------------------------------------------------------
    def set_tool(self, tool: str) -> None:
        if tool not in TOOLS:
            raise ValueError(f"unknown tool {tool!r}; one of {TOOLS}")
        self._tool = tool
        self._cursor.setVisible(tool in ("brush", "eraser"))
        self.viewport().setCursor(
            Qt.CursorShape.OpenHandCursor if tool == "pan" else Qt.CursorShape.PointingHandCursor if tool == "fill" else Qt.CursorShape.CrossCursor
        )

    @property
    def tool(self) -> str:
        return self._tool

    @property
    def brush_radius(self) -> float:
        return self._brush_radius

    def set_brush_radius(self, r: float) -> None:
        self._brush_radius = float(r)

    # -- Qt events -------------------------------------------------------------
    def resizeEvent(self, ev) -> None:
        super().resizeEvent(ev)
        if self._fitted:
            self.fit()

    def wheelEvent(self, ev) -> None:
        self.zoom(1.25 if ev.angleDelta().y() > 0 else 0.8)

    def _img_pos(self, ev) -> QPointF:
        return self.mapToScene(ev.position().toPoint())

    def mousePressEvent(self, ev) -> None:
        btn = ev.button()
        if btn in (Qt.MouseButton.MiddleButton, Qt.MouseButton.RightButton) or (btn == Qt.MouseButton.LeftButton and self._tool == "pan"):
            self._panning = ev.position()
            self.viewport().setCursor(Qt.CursorShape.ClosedHandCursor)
            return
        if btn == Qt.MouseButton.LeftButton:
            p = self._img_pos(ev)
            if self._tool in ("brush", "eraser"):
                self._stroking = True
                self.sigStrokePoint.emit(p.x(), p.y(), True)
            elif self._tool == "fill":
                self.sigPick.emit(p.x(), p.y())

    def mouseMoveEvent(self, ev) -> None:
        p = self._img_pos(ev)
        r = self._brush_radius
        self._cursor.setRect(p.x() - r, p.y() - r, 2 * r, 2 * r)
        self.sigHover.emit(p.x(), p.y())
        if self._panning is not None:
            d = ev.position() - self._panning
            self._panning = ev.position()
            self.horizontalScrollBar().setValue(self.horizontalScrollBar().value() - int(d.x()))
            self.verticalScrollBar().setValue(self.verticalScrollBar().value() - int(d.y()))
            return
        if self._stroking:
            self.sigStrokePoint.emit(p.x(), p.y(), False)

    def mouseReleaseEvent(self, ev) -> None:
        if self._panning is not None:
            self._panning = None
            self.set_tool(self._tool)
            return
        if self._stroking and ev.button() == Qt.MouseButton.LeftButton:
            self._stroking = False
            self.sigStrokeEnd.emit()
