"""Turns what the person does in the panels and the viewer into undoable commands on the Document.

The panels speak in rows of the mask list (index `i`); the Edits address a mask by its name, which
`Document.mask_name(i)` gives. The window wires the panels' and the viewer's signals to these methods.
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QObject, Signal
from PySide6.QtGui import QUndoStack
from PySide6.QtWidgets import QFileDialog, QProgressDialog, QWidget
from superqt.utils import WorkerBase, create_worker

from x2video.edits import Edits, Reference
from x2video.edits.propagate import propagate_mask
from x2video.io.image import read_image, write_exr
from x2video_app._qt.commands import MaskCommand, PaintCommand, SetValueCommand, SnapshotCommand
from x2video_app._qt.host import Host
from x2video_app.state.document import Document


class _Progress(QObject):
    """Carries (done, total) from a worker thread to the GUI thread (a queued signal)."""

    sig = Signal(int, int)


class EditActions(QObject):
    """sigTool(name) when the painting tool changes (the viewer and the mask panel follow it)."""

    sigTool = Signal(str)

    def __init__(self, doc: Document, undo: QUndoStack, host: Host, parent: QWidget | None = None) -> None:
        """`parent`: the widget the progress and file dialogs sit on."""
        super().__init__(parent)
        self.doc = doc
        self.undo = undo
        self.host = host
        self._dialog_parent = parent
        self.propagate_worker: Any = None  # the running mask propagation (superqt worker), if any
        self.propagate_progress: tuple[int, int] | None = None  # (frames done, total) the GUI last showed

    @property
    def e(self) -> Edits:
        return self.doc.edits

    def _set(self, key: tuple, text: str, setter, old, new, kind: str, final: bool = True) -> None:
        if old == new and final:
            return
        self.undo.push(SetValueCommand(self.doc, key, text, setter, old, new, kind, final=final))

    # -- painting --------------------------------------------------------------
    def set_tool(self, tool: str) -> None:
        self.sigTool.emit(tool)
        if tool in ("brush", "eraser", "fill") and self.doc.view not in ("masks", "albedo", "normal", "roughness", "metallic", "irradiance", "ids"):
            self.doc.set_view("masks")

    def stroke_point(self, x: float, y: float, starting: bool, radius: float, erase: bool) -> None:
        if starting:
            if self.doc.selected_mask < 0:
                self.add_mask()
            if self.doc.view not in ("masks",):
                self.doc.set_view("masks")
            self.doc.begin_stroke(x, y, radius, erase)
        else:
            self.doc.stroke_to(x, y, radius, erase)

    def stroke_end(self, erase: bool) -> None:
        res = self.doc.end_stroke()
        if res is not None:
            i, t, before, after = res
            self.undo.push(PaintCommand(self.doc, i, t, before, after, "Erase" if erase else "Paint stroke"))

    def pick(self, x: float, y: float) -> None:
        """Fill: add the object under the click (its id, on every frame) to the selected mask."""
        if self.doc.shot is not None and not self.doc.shot.has("ids"):
            self.host.status("This shot has no object ids: fill needs the ids channel.", 5000)
            return
        oid = self.doc.object_at(x, y)
        if oid is None:
            return
        if self.doc.selected_mask < 0:
            self.add_mask()
        name = self.doc.mask_name(self.doc.selected_mask)
        if oid in self.e.masks[name].ids:
            return
        cap = self.doc.shot.info.object_captions.get(oid, "")
        self.undo.push(MaskCommand(self.doc, name, f"Fill object {oid}" + (f" ({cap})" if cap else ""), lambda: self.e.masks[name].add_id(oid)))

    def clear_frame(self, i: int) -> None:
        t = self.doc.frame
        before = self.e.masks[self.doc.mask_name(i)].painted(t, self.doc.size)
        if before.any():
            self.undo.push(PaintCommand(self.doc, i, t, before, np.zeros_like(before), "Clear mask"))

    def propagate(self, i: int) -> Any:
        """Carry mask i from the current frame along the shot (optical flow) in a worker, with a progress
        dialog that can cancel; the window stays responsive. One undo step when it finishes, nothing
        when cancelled. Returns the worker (tests wait on it), or None when there is nothing to do."""
        t = self.doc.frame
        name = self.doc.mask_name(i)
        if self.propagate_worker is not None:
            self.host.status("A mask is already being propagated.", 5000)
            return None
        src = self.e.masks[name].painted(t, self.doc.size)
        if not src.any():
            self.host.status(f"Mask '{name}' is empty on frame {t}: paint it first.", 5000)
            return None
        shot = self.doc.shot
        dlg = QProgressDialog(f"Propagating '{name}' from frame {t} (optical flow)…", "Cancel", 0, max(1, self.doc.num_frames - 1), self._dialog_parent)
        dlg.setWindowTitle("Propagate mask")
        dlg.setMinimumDuration(400)
        progress = _Progress(dlg)  # lives on the GUI thread: the worker's emits are queued to it
        self.propagate_progress = None

        def show_progress(done: int, total: int) -> None:
            self.propagate_progress = (done, total)
            dlg.setMaximum(max(1, total))
            dlg.setValue(done)

        progress.sig.connect(show_progress)
        self.host.status(f"Propagating '{name}' along the shot (optical flow)…")

        def work() -> dict[int, np.ndarray]:
            return propagate_mask(shot, src, t, on_progress=progress.sig.emit, should_stop=lambda: worker.abort_requested)

        worker = create_worker(work)

        def returned(result: dict[int, np.ndarray]) -> None:  # superqt does not emit it after quit()
            if self.doc.shot is not shot or name not in self.e.masks:
                self.host.status(f"Propagation of '{name}' dropped: the shot or the mask changed meanwhile.", 5000)
            else:
                self.undo.push(MaskCommand(self.doc, name, f"Propagate {name} from frame {t}", lambda: self.e.masks[name].paint_frames(result)))
                self.host.status(f"Mask propagated from frame {t} to {len(result)} frames.", 5000)

        def failed(exc: BaseException) -> None:
            self.host.show_error("Mask propagation failed", f"{type(exc).__name__}: {exc}\n\nThe mask is unchanged.")

        def finished() -> None:
            dlg.reset()
            dlg.close()
            dlg.deleteLater()
            self.propagate_worker = None
            if worker.abort_requested:
                self.host.status(f"Propagation of '{name}' cancelled; the mask is unchanged.", 5000)

        worker.returned.connect(returned)
        worker.errored.connect(failed)
        worker.finished.connect(finished)
        dlg.canceled.connect(worker.quit)
        self.propagate_worker = worker
        worker.start()
        return worker

    def cancel_propagation(self, wait_ms: int = 10_000) -> None:
        """Stop a running propagation (closing the window) and wait for its thread."""
        w = self.propagate_worker
        if w is not None:
            w.quit()
            WorkerBase.await_workers(wait_ms)

    # -- masks -----------------------------------------------------------------
    def add_mask(self) -> None:
        n = self.doc.num_masks
        name = f"mask {n + 1}"
        self.undo.push(SnapshotCommand(self.doc, f"Add {name}", lambda: self.e.add_mask(name), select_after=n))
        self.doc.set_edit_global(False)

    def remove_mask(self, i: int) -> None:
        name = self.doc.mask_name(i)
        self.undo.push(SnapshotCommand(self.doc, f"Remove {name}", lambda: self.e.remove_mask(name), select_after=max(-1, i - 1)))

    def set_visible(self, i: int, on: bool) -> None:
        self.doc.set_mask_visible(i, on)

    def set_mask_colour(self, i: int, colour: tuple[int, int, int]) -> None:
        self._set(("colour", i), "Mask colour", lambda val: self.doc.set_mask_colour(i, val), self.doc.mask_colour(i), colour, "masks")

    def rename_mask(self, i: int, new: str) -> None:
        old = self.doc.mask_name(i)
        if new != old:
            self._set(("name", i), "Rename mask", lambda val: self._rename(i, val), old, new, "masks")

    def _rename(self, i: int, new: str) -> None:
        new = new.strip()  # a blank name keeps the old one (the list shows it again)
        if new and new != self.doc.mask_name(i):
            self.e.rename_mask(self.doc.mask_name(i), new)

    def set_mask_out(self, i: int, on: bool) -> None:
        name = self.doc.mask_name(i)
        self._set(("maskout", name), "Mask out A|M|R", lambda val: self.e.set_masked_out(name, val), self.e.masked_out(name), on, "masks")

    def set_local_prompt(self, i: int, text: str) -> None:
        name = self.doc.mask_name(i)
        self._set(("prompt", name), "Local prompt", lambda val: self.e.set_local_prompt(name, val), self.e.local_prompt(name), text, "prompts")

    def set_global_prompt(self, text: str) -> None:
        self._set(("gprompt",), "Global prompt", lambda val: setattr(self.e, "global_prompt", val), self.e.global_prompt, text, "prompts")

    def set_dropped(self, channel: str, on: bool) -> None:
        self._set(("drop", channel), f"{'Drop' if on else 'Keep'} {channel}", lambda val: self.e.set_dropped(channel, val), channel in self.e.dropped, on, "channels")

    # -- parametric edits ------------------------------------------------------
    def _tuning_target(self) -> str | None:
        """The mask (by name) the parametric edits apply to; None: the whole frame."""
        target = self.doc.edit_target()
        return None if target is None else self.doc.mask_name(target)

    def set_param(self, key: str, value: Any, final: bool) -> None:
        mask = self._tuning_target()
        old = self.e.tuning(mask).get(key)
        self._set(("param", mask, key), f"{key.replace('_', ' ')} ({mask or 'frame'})", lambda val: self.e.set_tuning(mask, key, val), old, value, "params", final)

    def reset_params(self) -> None:
        mask = self._tuning_target()
        self.undo.push(SnapshotCommand(self.doc, "Reset edits", lambda: self.e.reset_tuning(mask), select_after=self.doc.selected_mask))

    # -- reference -------------------------------------------------------------
    def load_reference_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self._dialog_parent, "Reference image", "", "Images (*.png *.jpg *.jpeg *.exr *.tif *.tiff)")
        if path:
            self.load_reference(path)

    def load_reference(self, path: str) -> bool:
        try:
            read_image(path).all()  # the whole file reads, or an error names it
        except Exception as e:  # a bad file: say which and keep the project
            self.host.show_error("Cannot read reference image", f"{path}:\n{e}")
            return False
        old = self.e.reference
        self._set(("reference",), "Load reference image", lambda val: setattr(self.e, "reference", val), old, Reference(path=str(Path(path).resolve())), "reference")
        return True

    def use_rendered_reference(self) -> bool:
        """Write the rendered current frame to an EXR (beside the project, else in the cache) and use it."""
        t = self.doc.frame
        img = self.doc.render.frames.get(t)
        if img is None:
            self.host.status(f"Frame {t} is not rendered yet: render it first or load an image.", 5000)
            return False
        folder = reference_folder(self.doc.project_path)
        path = folder / f"rendered_frame_{t:06d}_{int(time.time())}.exr"
        try:
            a = img.astype(np.float32)
            write_exr(path, {"R": a[..., 0], "G": a[..., 1], "B": a[..., 2]}, "half")
        except Exception as e:
            self.host.show_error("Cannot write the reference frame", f"{path}:\n{e}")
            return False
        self._set(("reference",), f"Use rendered frame {t} as reference", lambda val: setattr(self.e, "reference", val), self.e.reference, Reference(path=str(path), at=t), "reference")
        return True

    def clear_reference(self) -> None:
        self._set(("reference",), "Clear reference", lambda val: setattr(self.e, "reference", val), self.e.reference, None, "reference")


def reference_folder(project: Path | None) -> Path:
    """Where rendered frames used as references are written (they must outlive the session)."""
    if project is not None:
        return project.parent / (project.name.removesuffix(".json") + ".refs")
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "x2video" / "references"
