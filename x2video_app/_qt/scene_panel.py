"""Global controls: the global prompt, drop-channel toggles and the reference frame (load / use rendered / clear)."""
from __future__ import annotations

import numpy as np
from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QPixmap
from PySide6.QtWidgets import (
    QCheckBox,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from x2video.channels import INTRINSIC
from x2video_app._qt.viewer import qimage_from_u8
from x2video_app.state.display import channel_to_u8


class ScenePanel(QWidget):
    sigGlobalPrompt = Signal(str)
    sigDrop = Signal(str, bool)  # channel, dropped
    sigLoadReference = Signal()
    sigUseRendered = Signal()
    sigClearReference = Signal()

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.prompt = QLineEdit()
        self.prompt.setPlaceholderText("global prompt, e.g. 'a cosy living room in warm evening light'")
        self.prompt.editingFinished.connect(lambda: self.sigGlobalPrompt.emit(self.prompt.text()))
        pbox = QGroupBox("Global prompt")
        QVBoxLayout(pbox).addWidget(self.prompt)

        dbox = QGroupBox("Channels given to the model")
        grid = QGridLayout(dbox)
        self.keep: dict[str, QCheckBox] = {}
        for i, name in enumerate(INTRINSIC):
            cb = QCheckBox(name)
            cb.setChecked(True)
            cb.setToolTip(f"Untick to drop {name}: the model then infers it (paper: dropped channels)")
            cb.toggled.connect(lambda on, n=name: None if self._updating else self.sigDrop.emit(n, not on))
            grid.addWidget(cb, i // 3, i % 3)
            self.keep[name] = cb

        rbox = QGroupBox("Reference frame")
        self.ref_thumb = QLabel("none")
        self.ref_thumb.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.ref_thumb.setMinimumSize(120, 84)
        self.ref_thumb.setStyleSheet("QLabel { background: #202024; color: #bbb; border: 1px solid #555; }")
        self.ref_label = QLabel("")
        self.ref_label.setWordWrap(True)
        self.load_ref = QPushButton("Load image…")
        self.use_rendered = QPushButton("Use rendered frame")
        self.use_rendered.setToolTip("Use the rendered image of the current frame as the reference")
        self.clear_ref = QPushButton("Clear")
        self.load_ref.clicked.connect(self.sigLoadReference.emit)
        self.use_rendered.clicked.connect(self.sigUseRendered.emit)
        self.clear_ref.clicked.connect(self.sigClearReference.emit)
        brow = QHBoxLayout()
        for b in (self.load_ref, self.use_rendered, self.clear_ref):
            brow.addWidget(b)
        rl = QVBoxLayout(rbox)
        rl.addWidget(self.ref_thumb)
        rl.addWidget(self.ref_label)
        rl.addLayout(brow)

        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.addWidget(pbox)
        lay.addWidget(dbox)
        lay.addWidget(rbox)
        lay.addStretch(1)
        self._updating = False

    def set_values(self, global_prompt: str, dropped: set[str], reference: np.ndarray | None, ref_text: str) -> None:
        self._updating = True
        if self.prompt.text() != global_prompt:
            self.prompt.setText(global_prompt)
        for n, cb in self.keep.items():
            cb.setChecked(n not in dropped)
        if reference is None:
            self.ref_thumb.setPixmap(QPixmap())
            self.ref_thumb.setText("none")
        else:
            img = channel_to_u8("rgb", reference, reference.shape[:2])
            pm = QPixmap.fromImage(qimage_from_u8(img)).scaled(160, 112, Qt.AspectRatioMode.KeepAspectRatio, Qt.TransformationMode.SmoothTransformation)
            self.ref_thumb.setPixmap(pm)
        self.ref_label.setText(ref_text)
        self.clear_ref.setEnabled(reference is not None)
        self._updating = False
