"""Undo commands (QUndoStack) for painting and every edit; each calls back into the `Document`."""
from __future__ import annotations

import copy
from typing import Any, Callable

import numpy as np
from PySide6.QtGui import QUndoCommand

from x2video_app.state.document import Document

_MERGE_PARAM = 1001


class PaintCommand(QUndoCommand):
    """One brush/eraser stroke, id fill, or clear, on one mask of one frame (stores that frame's before/after)."""

    def __init__(self, doc: Document, mask: int, t: int, before: np.ndarray, after: np.ndarray, text: str = "Paint stroke") -> None:
        super().__init__(f"{text} (frame {t})")
        self.doc, self.mask, self.t = doc, mask, t
        self.before, self.after = before, after

    def redo(self) -> None:
        self.doc.set_mask_frame(self.mask, self.t, self.after)

    def undo(self) -> None:
        self.doc.set_mask_frame(self.mask, self.t, self.before)


class SnapshotCommand(QUndoCommand):
    """A structural change (add/remove mask, propagate, reference): whole-Edits before/after snapshots.

    `apply` mutates `doc.edits` in place; it runs on the first redo, later redos restore the
    after-snapshot so the outcome is identical however many times it is replayed.
    """

    def __init__(self, doc: Document, text: str, apply: Callable[[], Any], select_after: int | None = None) -> None:
        super().__init__(text)
        self.doc, self.apply, self.select_after = doc, apply, select_after
        self.before = doc.snapshot()
        self.sel_before = doc.selected_mask
        self.after: Any = None

    def redo(self) -> None:
        if self.after is None:
            self.apply()
            self.after = self.doc.snapshot()
            self.doc.restore(self.after, self.select_after)
        else:
            self.doc.restore(self.after, self.select_after)

    def undo(self) -> None:
        self.doc.restore(self.before, self.sel_before)


class MaskCommand(QUndoCommand):
    """A change of one whole mask (object-id fill, propagation): stores only that mask before/after."""

    def __init__(self, doc: Document, name: str, text: str, apply: Callable[[], Any]) -> None:
        super().__init__(text)
        self.doc, self.name, self.apply = doc, name, apply
        self.before = copy.deepcopy(doc.edits.masks[name])
        self.after: Any = None

    def redo(self) -> None:
        if self.after is None:
            self.apply()
            self.after = copy.deepcopy(self.doc.edits.masks[self.name])
        else:
            self.doc.edits.masks[self.name] = copy.deepcopy(self.after)
        self.doc.changed("mask")

    def undo(self) -> None:
        self.doc.edits.masks[self.name] = copy.deepcopy(self.before)
        self.doc.changed("mask")


class SetValueCommand(QUndoCommand):
    """Set one value through a setter; consecutive changes of the same key merge (slider drags, typing)."""

    def __init__(self, doc: Document, key: tuple, text: str, setter: Callable[[Any], None], old: Any, new: Any, kind: str, final: bool = True) -> None:
        super().__init__(text)
        self.doc, self.key, self.setter, self.old, self.new, self.kind = doc, key, setter, old, new, kind
        #: still taking in the values of a drag; a final value (slider released) closes it
        self.open = not final

    def id(self) -> int:
        return _MERGE_PARAM

    def mergeWith(self, other: QUndoCommand) -> bool:
        if not isinstance(other, SetValueCommand) or other.key != self.key or not self.open:
            return False
        self.new = other.new
        self.open = other.open
        return True

    def redo(self) -> None:
        self.setter(self.new)
        self.doc.changed(self.kind)

    def undo(self) -> None:
        self.setter(self.old)
        self.doc.changed(self.kind)
