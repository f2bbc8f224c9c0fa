"""Crash recovery in the editor: the undo history kept for autosave, the undo stack rebuilt from an autosave, and what
the person is asked and told. The files themselves are Qt-free (`x2video.edits.autosave`, `x2video.edits.lock`).

`HistoryTracker` follows the QUndoStack: after every push, undo, redo or merge (`indexChanged`) it keeps a snapshot
of the Edits at that index (the painted arrays shared, not copied), so an autosave holds every undo step's state and
`rebuild_undo` can give them back as undo steps after a crash.
"""
from __future__ import annotations

import itertools
import time
from pathlib import Path

from PySide6.QtGui import QUndoCommand, QUndoStack
from PySide6.QtWidgets import QMessageBox
from shiboken6 import isValid

from x2video.edits import Edits
from x2video.edits.autosave import Autosave, snapshot
from x2video_app._qt.host import Host
from x2video_app.state.document import Document

_TAGS = itertools.count(1)


def _tag(cmd: QUndoCommand) -> int:
    tag = getattr(cmd, "_x2v_tag", None)
    if tag is None:
        tag = next(_TAGS)
        cmd._x2v_tag = tag  # type: ignore[attr-defined]
    return tag


class HistoryTracker:
    """The Edits at each index of `undo` (index k: after k commands), kept as `undo` changes."""

    def __init__(self, doc: Document, undo: QUndoStack) -> None:
        self.doc, self.undo = doc, undo
        self.tags: list[int] = []
        self.labels: list[str] = []
        self.states: list[Edits | None] = [None]
        undo.indexChanged.connect(self._changed)
        doc.shot_changed.connect(self.reset)  # a shot opened: its Edits are state 0 (clearing an empty stack says nothing)

    def reset(self) -> None:
        self.tags, self.labels = [], []
        self.states = [None if self.doc.edits is None else snapshot(self.doc.edits)]

    def _changed(self, index: int) -> None:
        if not isValid(self.undo):  # the stack also reports while it is being destroyed
            return
        count = self.undo.count()
        tags = [_tag(self.undo.command(k)) for k in range(count)]
        if self.tags and tags and tags[0] != self.tags[0] and tags[0] in self.tags:  # an undo limit dropped the oldest
            drop = self.tags.index(tags[0])
            del self.tags[:drop], self.labels[:drop], self.states[:drop]
        n = 0
        while n < min(len(tags), len(self.tags)) and tags[n] == self.tags[n]:
            n += 1
        del self.tags[n:], self.labels[n:], self.states[n + 1:]
        for k in range(n, count):
            self.tags.append(tags[k])
            self.labels.append(self.undo.text(k))
            self.states.append(None)
        if self.doc.edits is not None:
            self.states[index] = snapshot(self.doc.edits)

    def autosave(self, shot: str, project: str | None, clean: bool) -> Autosave:
        """What to autosave now: the states known around the current index (`clean`: whether the undo stack's clean
        index is the project file's state)."""
        index = self.undo.index()
        if self.doc.edits is not None and not self.doc.stroking and self.states[index] != self.doc.edits:
            self.states[index] = snapshot(self.doc.edits)  # a change that bypassed the undo stack
        lo = index
        while lo > 0 and self.states[lo - 1] is not None:
            lo -= 1
        hi = index
        while hi + 1 < len(self.states) and self.states[hi + 1] is not None:
            hi += 1
        states = [s for s in self.states[lo:hi + 1] if s is not None]
        c = self.undo.cleanIndex()
        return Autosave(shot=shot, project=project, states=states, labels=self.labels[lo:hi], index=index - lo,
                        clean=c - lo if clean and lo <= c <= hi else None)


class RestoreCommand(QUndoCommand):
    """One undo step given back by recovery: the Edits before and after it."""

    def __init__(self, doc: Document, text: str, before: Edits, after: Edits) -> None:
        super().__init__(text)
        self.doc, self.before, self.after = doc, before, after

    def redo(self) -> None:
        self.doc.restore(self.after)

    def undo(self) -> None:
        self.doc.restore(self.before)


def rebuild_undo(undo: QUndoStack, doc: Document, saved: Autosave) -> bool:
    """Give the autosave's history back as undo steps (the document holds `saved.states[0]`); the project file's
    state, when one of them is, becomes the stack's clean state. Returns whether none is (the work must then count as
    unsaved whatever the stack says)."""
    undo.clear()
    for k, label in enumerate(saved.labels):
        undo.push(RestoreCommand(doc, label or f"Step {k + 1}", saved.states[k], saved.states[k + 1]))
    if saved.clean is not None:
        undo.setIndex(saved.clean)
        undo.setClean()
    undo.setIndex(saved.index)
    return saved.clean is None


def ask_recover(host: Host, found: str) -> bool:
    """Ask whether to recover the autosave that `found` describes."""
    yes, no = QMessageBox.StandardButton.Yes, QMessageBox.StandardButton.No
    return host.ask("Recover autosaved work?", f"{found} Recover it?", yes | no, yes) == yes


def describe(saved: Autosave, side: Path) -> str:
    when = time.ctime(saved.saved or side.stat().st_mtime)
    steps = f", with {len(saved.states) - 1} undo step(s)" if len(saved.states) > 1 else ""
    masks = len(saved.current.masks)
    return f"work autosaved {when}{steps} and {masks} mask(s)"


def tell_set_aside(host: Host, side: Path, reason: str, aside: Path, opens: str) -> None:
    host.show_error("Autosave could not be read",
                    f"{side}:\n{reason}\n\nIt was set aside as {aside.name} (kept, not read again); {opens}.")


def ask_open_locked(host: Host, message: str) -> bool:
    """A project open in another editor: open it here anyway (taking its lock over)?"""
    yes, no = QMessageBox.StandardButton.Yes, QMessageBox.StandardButton.No
    return host.ask("Project open elsewhere", f"{message}.\n\nOpen it here anyway? The two editors would overwrite "
                    "each other's saves and autosaves.", yes | no, no) == yes
