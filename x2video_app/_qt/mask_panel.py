"""Mask list and painting tools: brush/eraser with size, fill by object id, propagate, visibility, colour,
per-mask local prompt and the paper's "mask out A|M|R here" toggle."""
from __future__ import annotations

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QColor, QIcon, QPixmap
from PySide6.QtWidgets import (
    QButtonGroup,
    QCheckBox,
    QColorDialog,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QListWidget,
    QListWidgetItem,
    QPushButton,
    QStyledItemDelegate,
    QToolButton,
    QVBoxLayout,
    QWidget,
)
from superqt import QLabeledSlider

#: item data: what the mask list shows after a mask's name (its local prompt, whether A|M|R are masked out there)
NOTE_ROLE = Qt.ItemDataRole.UserRole + 1


def mask_note(prompt: str, mask_out: bool) -> str:
    """What a mask does, after its name in the list: 'A|M|R out · "its local prompt"'."""
    parts = (["A|M|R out"] if mask_out else []) + ([f"\u201c{prompt}\u201d"] if prompt else [])
    return " \u00b7 ".join(parts)


class MaskItemDelegate(QStyledItemDelegate):
    """Draws a mask's note (NOTE_ROLE) after its name; renaming still edits the name alone."""

    def initStyleOption(self, option, index) -> None:  # noqa: N802 (Qt)
        super().initStyleOption(option, index)
        note = index.data(NOTE_ROLE)
        if note:
            option.text = f"{option.text}  \u2014  {note}"


def swatch(rgb: tuple[int, int, int], size: int = 14) -> QIcon:
    pm = QPixmap(size, size)
    pm.fill(QColor(*rgb))
    return QIcon(pm)


class MaskPanel(QWidget):
    """A view of the document's masks; every user action is a signal the window turns into an undoable command."""

    sigAdd = Signal()
    sigRemove = Signal(int)
    sigSelect = Signal(int)  # -1 = none
    sigVisible = Signal(int, bool)
    sigColour = Signal(int, tuple)
    sigRename = Signal(int, str)
    sigPrompt = Signal(int, str)
    sigMaskOut = Signal(int, bool)
    sigTool = Signal(str)
    sigBrushSize = Signal(int)
    sigPropagate = Signal(int)
    sigClearFrame = Signal(int)

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.list = QListWidget()
        self.list.setMinimumHeight(60)
        self.list.setItemDelegate(MaskItemDelegate(self.list))
        self.list.setTextElideMode(Qt.TextElideMode.ElideRight)  # a long prompt ends in '…' (the Prompt field has it whole)
        self.list.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.list.setToolTip("Masks: tick to show in the overlay, double-click to rename")
        self.add_button = QPushButton("Add mask")
        self.remove_button = QPushButton("Remove")
        self.colour_button = QPushButton("Colour…")
        row = QHBoxLayout()
        for b in (self.add_button, self.remove_button, self.colour_button):
            row.addWidget(b)

        self.tools = QButtonGroup(self)
        tool_row = QHBoxLayout()
        self.tool_buttons: dict[str, QToolButton] = {}
        for name, tip in (
            ("brush", "Paint the selected mask (B)"),
            ("eraser", "Erase from the selected mask (E)"),
            ("fill", "Click an object to add its id region to the mask (F)"),
            ("pan", "Drag to pan (P); the wheel zooms, right-drag always pans"),
        ):
            b = QToolButton()
            b.setText(name.capitalize())
            b.setCheckable(True)
            b.setToolTip(tip)
            b.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextOnly)
            self.tools.addButton(b)
            self.tool_buttons[name] = b
            tool_row.addWidget(b)
            b.clicked.connect(lambda _=False, n=name: self.sigTool.emit(n))
        self.tool_buttons["brush"].setChecked(True)
        self.size = QLabeledSlider(Qt.Orientation.Horizontal)
        self.size.setRange(1, 64)
        self.size.setValue(8)
        self.size.setToolTip("Brush radius in shot pixels")
        self.size.valueChanged.connect(self.sigBrushSize.emit)

        self.prompt = QLineEdit()
        self.prompt.setPlaceholderText("local prompt for this mask, e.g. 'a red leather sofa'")
        self.prompt.editingFinished.connect(self._prompt_done)
        self.mask_out = QCheckBox("Mask out A|M|R here")
        self.mask_out.setToolTip("Zero albedo, metallic and roughness inside this mask; the model fills the material in (paper: Mask A|M|R)")
        self.mask_out.toggled.connect(lambda on: self._emit_selected(self.sigMaskOut, on))
        self.propagate_button = QPushButton("Propagate this frame along the shot")
        self.propagate_button.setToolTip("Carry the selected mask on the current frame to every frame with optical flow")
        self.clear_button = QPushButton("Clear on this frame")
        self.coverage = QLabel("")
        self.coverage.setWordWrap(True)
        self.coverage.setMinimumHeight(2 * self.coverage.fontMetrics().lineSpacing() + 2)

        grid = QGridLayout()
        grid.addWidget(QLabel("Tool"), 0, 0)
        grid.addLayout(tool_row, 0, 1)
        grid.addWidget(QLabel("Size"), 1, 0)
        grid.addWidget(self.size, 1, 1)
        grid.addWidget(QLabel("Prompt"), 2, 0)
        grid.addWidget(self.prompt, 2, 1)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.addWidget(self.list, 1)
        lay.addLayout(row)
        lay.addLayout(grid)
        lay.addWidget(self.mask_out)
        prow = QHBoxLayout()
        prow.addWidget(self.propagate_button, 1)
        prow.addWidget(self.clear_button)
        lay.addLayout(prow)
        lay.addWidget(self.coverage)

        self.add_button.clicked.connect(self.sigAdd.emit)
        self.remove_button.clicked.connect(lambda: self._emit_selected(self.sigRemove))
        self.colour_button.clicked.connect(self._pick_colour)
        self.propagate_button.clicked.connect(lambda: self._emit_selected(self.sigPropagate))
        self.clear_button.clicked.connect(lambda: self._emit_selected(self.sigClearFrame))
        self.list.currentRowChanged.connect(self.sigSelect.emit)
        self.list.itemChanged.connect(self._item_changed)
        self._colours: list[tuple[int, int, int]] = []
        self._updating = False
        self.setMinimumHeight(self.sizeHint().height())  # docks must not squeeze wrapped labels into each other

    # -- refresh from the document --------------------------------------------
    def set_masks(self, masks: list[dict], selected: int) -> None:
        """masks: [{"name", "colour", "visible", "prompt", "mask_out"}]"""
        self._updating = True
        self.list.blockSignals(True)
        self.list.clear()
        self._colours = [m["colour"] for m in masks]
        for m in masks:
            it = QListWidgetItem(swatch(m["colour"]), m["name"])
            it.setFlags(it.flags() | Qt.ItemFlag.ItemIsUserCheckable | Qt.ItemFlag.ItemIsEditable)
            it.setCheckState(Qt.CheckState.Checked if m["visible"] else Qt.CheckState.Unchecked)
            it.setData(NOTE_ROLE, mask_note(m.get("prompt") or "", bool(m.get("mask_out"))))
            if m.get("prompt"):
                it.setToolTip(f"prompt: {m['prompt']}")
            self.list.addItem(it)
        self.list.setCurrentRow(selected)
        self.list.blockSignals(False)
        has = 0 <= selected < len(masks)
        for w in (self.remove_button, self.colour_button, self.prompt, self.mask_out, self.propagate_button, self.clear_button):
            w.setEnabled(has)
        self.prompt.setText(masks[selected]["prompt"] if has else "")
        self.prompt.setCursorPosition(0)
        self.mask_out.blockSignals(True)
        self.mask_out.setChecked(bool(masks[selected]["mask_out"]) if has else False)
        self.mask_out.blockSignals(False)
        self._updating = False

    def set_coverage(self, text: str) -> None:
        self.coverage.setText(text)

    def set_tool(self, name: str) -> None:
        self.tool_buttons[name].setChecked(True)

    # -- internals -------------------------------------------------------------
    def selected(self) -> int:
        return self.list.currentRow()

    def _emit_selected(self, sig, *args) -> None:
        if not self._updating and self.selected() >= 0:
            sig.emit(self.selected(), *args)

    def _prompt_done(self) -> None:
        self._emit_selected(self.sigPrompt, self.prompt.text())

    def _pick_colour(self) -> None:
        i = self.selected()
        if i < 0:
            return
        c = QColorDialog.getColor(QColor(*self._colours[i]), self, "Mask colour")
        if c.isValid():
            self.sigColour.emit(i, (c.red(), c.green(), c.blue()))

    def _item_changed(self, it: QListWidgetItem) -> None:
        if self._updating:
            return
        i = self.list.row(it)
        self.sigVisible.emit(i, it.checkState() == Qt.CheckState.Checked)
        self.sigRename.emit(i, it.text())
