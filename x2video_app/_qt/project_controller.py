"""Opening shots, projects and the demo; saving; autosave (with the undo history) to a side file with recovery after a
crash; a lock file that tells a second editor the project is open; and the unsaved-changes guard (export:
`x2video_app._qt.export_controller`). Works on the Document, the undo stack (clean = saved) and the render
controller it is given; asks and reports through a `Host`. The files are Qt-free: `x2video.edits.autosave`,
`x2video.edits.lock`; the undo side is `x2video_app._qt.recovery`."""
from __future__ import annotations

import logging
import os
from pathlib import Path

from PySide6.QtCore import QObject, Qt, QTimer, Signal
from PySide6.QtGui import QUndoStack
from PySide6.QtWidgets import QApplication, QFileDialog, QMessageBox, QProgressDialog, QWidget
from shiboken6 import isValid

from x2video.demo import STATED_TIME
from x2video.edits import PROJECT_SUFFIX, Project, is_project_file, load_project, save_project
from x2video.edits.autosave import (
    AutosaveError,
    autosave_path,
    crashed_sessions,
    forget_session,
    note_session,
    read_autosave,
    remove_autosave,
    set_aside,
    write_autosave,
)
from x2video.edits.lock import ProjectLock, ProjectLocked
from x2video.io import load_shot
from x2video_app._qt import recovery
from x2video_app._qt.host import Host
from x2video_app._qt.render_controller import RenderController
from x2video_app.state.demo import ensure_demo
from x2video_app.state.document import Document

log = logging.getLogger(__name__)


#: how often the editor autosaves when it is not told (milliseconds)
AUTOSAVE_MS = 180_000


def default_autosave_ms() -> int:
    """The autosave interval of an editor that is not given one: `AUTOSAVE_MS`, or the environment's
    X2VIDEO_AUTOSAVE_MS (milliseconds; 0: no timed autosave) where that is set. The SIGKILL test of the editor
    (tests/faults/test_app_sigkill.py) shortens it, so the editor's own timer autosaves while the test kills it."""
    env = os.environ.get("X2VIDEO_AUTOSAVE_MS", "").strip()
    try:
        return max(0, int(env)) if env else AUTOSAVE_MS
    except ValueError:
        log.warning("X2VIDEO_AUTOSAVE_MS=%r is not a number of milliseconds: autosaving every %d ms", env, AUTOSAVE_MS)
        return AUTOSAVE_MS


def lock_target(project: Path | None, shot_path: str | None) -> Path:
    """What the lock guards: the project file, or an unsaved shot's autosave."""
    return project if project is not None else autosave_path(None, shot_path)


class ProjectController(QObject):
    """sigTitle(text, modified): what the window's title should say, and whether there are unsaved changes."""

    sigTitle = Signal(str, bool)

    def __init__(self, doc: Document, undo: QUndoStack, render_ctl: RenderController, host: Host,
                 parent: QWidget | None = None, autosave_ms: int | None = None) -> None:
        """`parent`: the widget the file and progress dialogs sit on; `autosave_ms`: the autosave interval (0: only
        when called; None: `default_autosave_ms()`)."""
        super().__init__(parent)
        self.doc = doc
        self.undo = undo
        self.render_ctl = render_ctl
        self.host = host
        self._dialog_parent = parent
        self.timer = QTimer(self)
        self.timer.timeout.connect(self.autosave)
        if autosave_ms is None:
            autosave_ms = default_autosave_ms()
        if autosave_ms > 0:
            self.timer.start(autosave_ms)
        #: recovered autosave: unsaved under the project's name although the undo stack is clean
        self.force_dirty = False
        undo.cleanChanged.connect(self._clean_changed)
        #: the Edits at each undo index, for autosave (`x2video_app._qt.recovery`)
        self.history = recovery.HistoryTracker(doc, undo)
        #: the lock of the open project (or unsaved shot); None when nothing is open
        self.lock: ProjectLock | None = None

    # -- title / dirty ---------------------------------------------------------
    def _clean_changed(self, _clean: bool) -> None:
        if isValid(self.undo):  # the undo stack also reports while it is being destroyed
            self.update_title()

    @property
    def dirty(self) -> bool:
        return self.force_dirty or not self.undo.isClean()

    def update_title(self) -> None:
        name = self.doc.project_path.name if self.doc.project_path else (Path(self.doc.shot_path).name if self.doc.shot_path else "untitled")
        self.sigTitle.emit(f"{name}[*] — X2Video Studio", self.dirty)

    def confirm_discard(self, what: str) -> bool:
        """True when there are no unsaved changes, or the person chose to save or discard them."""
        if not self.dirty:
            return True
        b = self.host.ask(
            "Unsaved changes",
            f"The project has unsaved changes. Save them before you {what}?",
            QMessageBox.StandardButton.Save | QMessageBox.StandardButton.Discard | QMessageBox.StandardButton.Cancel,
            QMessageBox.StandardButton.Save,
        )
        if b == QMessageBox.StandardButton.Save:
            return self.save()
        if b == QMessageBox.StandardButton.Discard:
            remove_autosave(autosave_path(self.doc.project_path, self.doc.shot_path))  # nothing to recover later
            return True
        return False

    # -- the lock ----------------------------------------------------------------
    def _take_lock(self, project: Path | None, shot_path: str | None) -> bool:
        """Lock what is about to open; a project open in another editor is opened only if the person says so."""
        lock = ProjectLock(lock_target(project, shot_path))
        try:
            how = lock.acquire()
        except ProjectLocked as exc:
            if not recovery.ask_open_locked(self.host, str(exc)):
                return False
            how = lock.acquire(take_over=True)
        if how.startswith("stale"):
            log.info("%s: took over a stale lock (%s)", lock.path, how)
            self.host.status(f"Took over the lock of {lock.target.name} ({how.removeprefix('stale: ')})", 8000)
        self._release_lock()
        self.lock = lock
        return True

    def _release_lock(self) -> None:
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    # -- recovery ------------------------------------------------------------------
    def _read_side(self, side: Path, opens: str, shot: str | None = None):
        """The autosave at `side` (None: none, damaged and set aside, or of another shot)."""
        if not side.is_file():
            return None
        try:
            saved = read_autosave(side)
        except AutosaveError as exc:
            aside = set_aside(side)
            log.warning("autosave %s: %s; set aside as %s", side, exc.reason, aside)
            recovery.tell_set_aside(self.host, side, exc.reason, aside, opens)
            forget_session(side)
            return None
        if shot is not None and Path(saved.shot).resolve() != Path(shot).resolve():
            return None  # another shot's (an older autosave name could be shared by two shots of one name)
        return saved

    def _restore(self, saved, shot, shot_path: str, project_path: Path | None) -> None:
        """Open the autosave's current state with its undo history."""
        self.doc.set_shot(shot, shot_path, saved.states[0], project_path=project_path)
        self.force_dirty = recovery.rebuild_undo(self.undo, self.doc, saved)
        side = autosave_path(project_path, shot_path)
        if side.is_file():  # the restored work is this editor's now: killed before its first autosave, the next start offers it
            try:
                note_session(side, str(Path(shot_path).resolve()), None if project_path is None else str(Path(project_path).resolve()))
            except OSError as e:
                log.warning("could not register the recovered session %s: %s", side, e)

    # -- opening ---------------------------------------------------------------
    def open_shot_dialog(self) -> None:
        path = QFileDialog.getExistingDirectory(self._dialog_parent, "Open shot folder")
        if path:
            self.open_path(path)

    def open_project_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self._dialog_parent, "Open project", "", f"X2Video project (*{PROJECT_SUFFIX} *.json)")
        if path:
            self.open_path(path)

    def open_path(self, path: str | Path, recover: bool | None = None) -> bool:
        """Open a shot (folder or file the loaders read) or a project file; errors keep the current project. An
        autosave left by a crash is offered (`recover`: True/False answers for the person)."""
        p = Path(path)
        if not self.confirm_discard("open another file"):
            return False
        if self.render_ctl.running:  # its frames belong to the shot being closed
            self.render_ctl.cancel()
            self.render_ctl.wait(120_000)
        try:
            if is_project_file(p):
                return self._open_project(p, recover=recover)
            shot = load_shot(p)
        except Exception as e:
            self.host.show_error("Cannot open", f"{p}:\n{e}")
            return False
        if not self._take_lock(None, str(p)):
            return False
        self.doc.set_shot(shot, str(p))
        self.force_dirty = False
        side = autosave_path(None, str(p))
        saved = self._read_side(side, f"{p.name} opens without it", shot=str(p))
        if saved is not None:
            found = f"Unsaved work on {p.name} was autosaved ({recovery.describe(saved, side)}), probably before a crash."
            if recover if recover is not None else recovery.ask_recover(self.host, found):
                self._restore(saved, shot, str(p), None)
                self.force_dirty = True
            else:
                remove_autosave(side)
        self.update_title()
        self.host.status(f"Opened {p} ({shot.num_frames} frames, {shot.size[1]}×{shot.size[0]}, channels: {', '.join(shot.channels)})", 8000)
        return True

    def _open_project(self, p: Path, recover: bool | None = None) -> bool:
        project = load_project(p)
        shot = load_shot(project.shot)
        if not self._take_lock(p, None):
            return False
        side = autosave_path(p, None)
        saved = None
        if side.exists() and side.stat().st_mtime > p.stat().st_mtime:
            saved = self._read_side(side, f"{p.name} opens as last saved")
        if saved is not None:
            found = f"An autosave newer than {p.name} exists ({recovery.describe(saved, side)}), probably from a crash."
            if not (recover if recover is not None else recovery.ask_recover(self.host, found)):
                saved = None
        if saved is not None:
            self._restore(saved, shot, project.shot, p)
        else:
            self.doc.set_shot(shot, project.shot, project.edits, project_path=p)
            self.force_dirty = False
        self.update_title()
        self.host.status(f"Opened project {p}", 8000)
        return True

    def offer_crashed(self) -> bool:
        """At start: offer the newest autosave of an editor that ended without saving (its process is gone); True when
        it was opened. Asked once: declined, it stays beside its project and is offered when that is opened."""
        for entry in crashed_sessions():
            side, target = Path(entry["autosave"]), entry.get("project") or entry.get("shot")
            forget_session(side)
            if not target or not Path(target).exists():
                continue
            saved = self._read_side(side, "nothing is recovered")
            if saved is None:
                continue
            found = (f"X2Video Studio stopped without saving (pid {entry.get('pid')}): {Path(target).name} has "
                     f"{recovery.describe(saved, side)}.")
            if recovery.ask_recover(self.host, found):
                return self.open_path(target, recover=True)
            return False
        return False

    def open_demo(self) -> bool:
        """Open the demo shot, making it first if it is not cached: a busy dialog, which becomes a progress bar with the
        frames left while Cycles path-traces the room (the first start only); why it is the rasterized room, if it is,
        goes to the status bar."""
        dlg = QProgressDialog("Preparing the demo shot (made once)…", None, 0, 0, self._dialog_parent)
        dlg.setWindowTitle("X2Video Studio")
        dlg.setWindowModality(Qt.WindowModality.WindowModal)
        dlg.setMinimumDuration(500)
        dlg.setAutoReset(False)  # it stays up after the last frame, while the room's shot is finished and opened
        dlg.setAutoClose(False)
        notes: list[str] = []
        frame_s: list[float] = []

        def progress(done: int, total: int, seconds: float) -> None:
            dlg.setMaximum(total)
            dlg.setValue(done)
            frame_s.extend([seconds] if done else [])
            left = f", about {sum(frame_s) / len(frame_s) * (total - done):.0f} s left" if frame_s else ""
            dlg.setLabelText(f"Path-tracing the demo room with Cycles, once ({STATED_TIME.removesuffix(', once')}):\n"
                             + (f"frame {done} of {total}{left}" if done else "building the room…"))

        try:
            d = ensure_demo(poll=QApplication.processEvents, on_progress=progress, on_note=notes.append)
        except Exception as e:
            self.host.show_error("Cannot make the demo shot", f"{e}\n\nOpen a shot folder with File → Open shot.")
            return False
        finally:
            dlg.reset()
            dlg.close()
        opened = self.open_path(d)
        if opened and notes:
            self.host.status(f"Demo: {notes[-1]}", 15000)
        return opened

    # -- saving ----------------------------------------------------------------
    def save(self) -> bool:
        if self.doc.shot is None:
            return False
        if self.doc.project_path is None:
            return self.save_as()
        return self.save_to(self.doc.project_path)

    def save_as(self) -> bool:
        if self.doc.shot is None:
            return False
        path, _ = QFileDialog.getSaveFileName(self._dialog_parent, "Save project", f"project{PROJECT_SUFFIX}", f"X2Video project (*{PROJECT_SUFFIX})")
        return bool(path) and self.save_to(Path(path))

    def save_to(self, path: Path) -> bool:
        try:
            self._write_project(path)
        except Exception as e:
            self.host.show_error("Cannot save project", f"{path}:\n{e}")
            return False
        old_side = autosave_path(self.doc.project_path, self.doc.shot_path)
        if self.lock is None or self.lock.target != Path(path):
            self._take_lock(Path(path), None)  # saved under a new name: that file is now the one held
        self.doc.project_path = Path(path)
        self.undo.setClean()
        self.force_dirty = False
        for side in {old_side, autosave_path(self.doc.project_path, None)}:
            remove_autosave(side)
        self.update_title()
        self.host.status(f"Saved {path}", 5000)
        return True

    def _write_project(self, path: Path) -> None:
        if not self.doc.shot_path:
            raise ValueError("the project has no shot file to refer to")
        save_project(path, Project(shot=str(Path(self.doc.shot_path).resolve()), edits=self.doc.edits))

    def autosave(self) -> Path | None:
        """Write the side file (the undo history's states, masks included) when there are unsaved changes (timer;
        also callable directly)."""
        if self.doc.shot is None or not self.dirty or not self.doc.shot_path:
            return None
        side = autosave_path(self.doc.project_path, self.doc.shot_path)
        shot = str(Path(self.doc.shot_path).resolve())
        project = None if self.doc.project_path is None else str(self.doc.project_path.resolve())
        try:
            write_autosave(side, self.history.autosave(shot, project, clean=not self.force_dirty))
            note_session(side, shot, project)
        except Exception as e:  # autosave must never interrupt the person
            log.warning("autosave to %s failed: %s", side, e)
            self.host.status(f"Autosave to {side} failed: {e}", 8000)
            return None
        self.host.status(f"Autosaved to {side}", 3000)
        return side

    def shutdown(self) -> None:
        """Clean exit: nothing left to recover."""
        self.timer.stop()
        side = autosave_path(self.doc.project_path, self.doc.shot_path)
        if not self.dirty:
            remove_autosave(side)
        else:
            forget_session(side)  # a clean exit that chose to keep the autosave: offered when that project opens
        self._release_lock()
