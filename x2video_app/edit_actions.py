"""Turns what the person does in the panels and the viewer into undoable commands on the Document."""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import QObject, Signal
from PySide6.QtWidgets import QFileDialog, QProgressDialog
from superqt.utils import create_worker

from x2video.edits.propagate import propagate_mask
from x2video.io.image import write_exr
from x2video_app import edit_ops
from x2video_app.commands import MaskCommand, PaintCommand, SetValueCommand, SnapshotCommand
from x2video_app.display import MASK_COLOURS

if TYPE_CHECKING:
    from x2video_app.main_window import MainWindow


class _Progress(QObject):
    """Carries (done, total) from a worker thread to the GUI thread (a queued signal)."""

    sig = Signal(int, int)


class EditActions(QObject):
    def __init__(self, win: "MainWindow") -> None:
        super().__init__(win)
        self.win = win
        self.doc = win.doc
        self.undo = win.undo
        self._erase = False
        self.propagate_worker: Any = None  # the running mask propagation (superqt worker), if any
        self.propagate_progress: tuple[int, int] | None = None  # (frames done, total) the GUI last showed
        self._connect()

    @property
    def e(self) -> Any:
        return self.doc.edits

    def _connect(self) -> None:
        w, mp, ep, sp = self.win, self.win.mask_panel, self.win.edit_panel, self.win.scene_panel
        v = w.viewer
        v.sigStrokePoint.connect(self.stroke_point)
        v.sigStrokeEnd.connect(self.stroke_end)
        v.sigPick.connect(self.pick)
        mp.sigTool.connect(self.set_tool)
        mp.sigBrushSize.connect(v.set_brush_radius)
        mp.sigAdd.connect(self.add_mask)
        mp.sigRemove.connect(self.remove_mask)
        mp.sigSelect.connect(self.doc.select_mask)
        mp.sigVisible.connect(self.set_visible)
        mp.sigColour.connect(lambda i, c: self._set(("colour", i), "Mask colour", lambda val: self.doc.set_mask_colour(i, val), self.doc.mask_colour(i), c, "masks"))
        mp.sigRename.connect(lambda i, n: None if n == edit_ops.mask_name(self.e, i) else self._set(("name", i), "Rename mask", lambda val: edit_ops.set_mask_name(self.e, i, val), edit_ops.mask_name(self.e, i), n, "masks"))
        mp.sigPrompt.connect(self.set_local_prompt)
        mp.sigMaskOut.connect(lambda i, on: self._set(("maskout", i), "Mask out A|M|R", lambda val: edit_ops.set_mask_out(self.e, i, val), edit_ops.mask_out(self.e, i), on, "masks"))
        mp.sigPropagate.connect(self.propagate)
        mp.sigClearFrame.connect(self.clear_frame)
        ep.sigParam.connect(self.set_param)
        ep.sigTarget.connect(self.doc.set_edit_global)
        ep.sigReset.connect(self.reset_params)
        sp.sigGlobalPrompt.connect(self.set_global_prompt)
        sp.sigDrop.connect(lambda n, on: self._set(("drop", n), f"{'Drop' if on else 'Keep'} {n}", lambda val: edit_ops.set_dropped(self.e, n, val), n in edit_ops.dropped(self.e), on, "channels"))
        sp.sigLoadReference.connect(self.load_reference_dialog)
        sp.sigUseRendered.connect(self.use_rendered_reference)
        sp.sigClearReference.connect(self.clear_reference)

    def _set(self, key: tuple, text: str, setter, old, new, kind: str, final: bool = True) -> None:
        if old == new and final:
            return
        self.undo.push(SetValueCommand(self.doc, key, text, setter, old, new, kind, final=final))

    # -- painting --------------------------------------------------------------
    def set_tool(self, tool: str) -> None:
        self.win.viewer.set_tool(tool)
        self.win.mask_panel.set_tool(tool)
        if tool in ("brush", "eraser", "fill") and self.doc.view not in ("masks", "albedo", "normal", "roughness", "metallic", "irradiance", "ids"):
            self.doc.set_view("masks")

    def stroke_point(self, x: float, y: float, starting: bool) -> None:
        r = self.win.viewer._brush_radius
        erase = self.win.viewer.tool == "eraser"
        if starting:
            if self.doc.selected_mask < 0:
                self.add_mask()
            if self.doc.view not in ("masks",):
                self.doc.set_view("masks")
            self.doc.begin_stroke(x, y, r, erase)
        else:
            self.doc.stroke_to(x, y, r, erase)

    def stroke_end(self) -> None:
        res = self.doc.end_stroke()
        if res is not None:
            i, t, before, after = res
            self.undo.push(PaintCommand(self.doc, i, t, before, after, "Erase" if self.win.viewer.tool == "eraser" else "Paint stroke"))

    def pick(self, x: float, y: float) -> None:
        """Fill: add the object under the click (its id, on every frame) to the selected mask."""
        if self.doc.shot is not None and not self.doc.shot.has("ids"):
            self.win.statusBar().showMessage("This shot has no object ids: fill needs the ids channel.", 5000)
            return
        oid = self.doc.object_at(x, y)
        if oid is None:
            return
        if self.doc.selected_mask < 0:
            self.add_mask()
        i = self.doc.selected_mask
        if oid in edit_ops.mask_ids(self.e, i):
            return
        name = edit_ops.mask_name(self.e, i)
        cap = self.doc.shot.info.object_captions.get(oid, "")
        self.undo.push(MaskCommand(self.doc, name, f"Fill object {oid}" + (f" ({cap})" if cap else ""), lambda: edit_ops.add_mask_id(self.e, i, oid)))

    def clear_frame(self, i: int) -> None:
        t = self.doc.frame
        before = edit_ops.get_mask(self.e, i, t, self.doc.size)
        if before.any():
            self.undo.push(PaintCommand(self.doc, i, t, before, np.zeros_like(before), "Clear mask"))

    def propagate(self, i: int) -> Any:
        """Carry mask i from the current frame along the shot (optical flow) in a worker, with a progress
        dialog that can cancel; the window stays responsive. One undo step when it finishes, nothing
        when cancelled. Returns the worker (tests wait on it), or None when there is nothing to do."""
        t = self.doc.frame
        name = edit_ops.mask_name(self.e, i)
        if self.propagate_worker is not None:
            self.win.statusBar().showMessage("A mask is already being propagated.", 5000)
            return None
        src = edit_ops.get_mask(self.e, i, t, self.doc.size)
        if not src.any():
            self.win.statusBar().showMessage(f"Mask '{name}' is empty on frame {t}: paint it first.", 5000)
            return None
        shot = self.doc.shot
        dlg = QProgressDialog(f"Propagating '{name}' from frame {t} (optical flow)…", "Cancel", 0, max(1, self.doc.num_frames - 1), self.win)
        dlg.setWindowTitle("Propagate mask")
        dlg.setMinimumDuration(400)
        progress = _Progress(dlg)  # lives on the GUI thread: the worker's emits are queued to it
        self.propagate_progress = None

        def show_progress(done: int, total: int) -> None:
            self.propagate_progress = (done, total)
            dlg.setMaximum(max(1, total))
            dlg.setValue(done)

        progress.sig.connect(show_progress)
        self.win.statusBar().showMessage(f"Propagating '{name}' along the shot (optical flow)…")

        def work() -> dict[int, np.ndarray]:
            return propagate_mask(shot, src, t, on_progress=progress.sig.emit, should_stop=lambda: worker.abort_requested)

        worker = create_worker(work)

        def returned(result: dict[int, np.ndarray]) -> None:  # superqt does not emit it after quit()
            if self.doc.shot is not shot or name not in self.e.masks:
                self.win.statusBar().showMessage(f"Propagation of '{name}' dropped: the shot or the mask changed meanwhile.", 5000)
            else:
                self.undo.push(MaskCommand(self.doc, name, f"Propagate {name} from frame {t}", lambda: edit_ops.paint_frames(self.e, name, result)))
                self.win.statusBar().showMessage(f"Mask propagated from frame {t} to {len(result)} frames.", 5000)

        def failed(exc: BaseException) -> None:
            self.win.show_error("Mask propagation failed", f"{type(exc).__name__}: {exc}\n\nThe mask is unchanged.")

        def finished() -> None:
            dlg.reset()
            dlg.close()
            dlg.deleteLater()
            self.propagate_worker = None
            if worker.abort_requested:
                self.win.statusBar().showMessage(f"Propagation of '{name}' cancelled; the mask is unchanged.", 5000)

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
            from superqt.utils._qthreading import WorkerBase

            WorkerBase.await_workers(wait_ms)

    # -- masks -----------------------------------------------------------------
    def add_mask(self) -> None:
        n = edit_ops.num_masks(self.e)
        name = f"mask {n + 1}"
        colour = MASK_COLOURS[n % len(MASK_COLOURS)]
        self.undo.push(SnapshotCommand(self.doc, f"Add {name}", lambda: edit_ops.add_mask(self.e, name, colour), select_after=n))
        self.doc.set_edit_global(False)

    def remove_mask(self, i: int) -> None:
        name = edit_ops.mask_name(self.e, i)
        self.undo.push(SnapshotCommand(self.doc, f"Remove {name}", lambda: edit_ops.remove_mask(self.e, i), select_after=max(-1, i - 1)))

    def set_visible(self, i: int, on: bool) -> None:
        self.doc.set_mask_visible(i, on)

    def set_local_prompt(self, i: int, text: str) -> None:
        self._set(("prompt", i), "Local prompt", lambda val: edit_ops.set_mask_prompt(self.e, i, val), edit_ops.mask_prompt(self.e, i), text, "prompts")

    def set_global_prompt(self, text: str) -> None:
        self._set(("gprompt",), "Global prompt", lambda val: edit_ops.set_global_prompt(self.e, val), edit_ops.global_prompt(self.e), text, "prompts")

    # -- parametric edits ------------------------------------------------------
    def set_param(self, key: str, value: Any, final: bool) -> None:
        target = self.doc.edit_target()
        old = edit_ops.get_params(self.e, target).get(key)
        where = "frame" if target is None else edit_ops.mask_name(self.e, target)
        self._set(("param", target, key), f"{key.replace('_', ' ')} ({where})", lambda val, t=target, k=key: edit_ops.set_param(self.e, t, k, val), old, value, "params", final)

    def reset_params(self) -> None:
        target = self.doc.edit_target()
        self.undo.push(SnapshotCommand(self.doc, "Reset edits", lambda: edit_ops.reset_params(self.e, target), select_after=self.doc.selected_mask))

    # -- reference -------------------------------------------------------------
    def load_reference_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self.win, "Reference image", "", "Images (*.png *.jpg *.jpeg *.exr *.tif *.tiff)")
        if path:
            self.load_reference(path)

    def load_reference(self, path: str) -> bool:
        try:
            edit_ops.read_image(path)
        except Exception as e:  # a bad file: say which and keep the project
            self.win.show_error("Cannot read reference image", f"{path}:\n{e}")
            return False
        old = self.e.reference
        self._set(("reference",), "Load reference image", lambda val: setattr(self.e, "reference", val), old, edit_ops.Reference(path=str(Path(path).resolve())), "reference")
        return True

    def use_rendered_reference(self) -> bool:
        """Write the rendered current frame to an EXR (beside the project, else in the cache) and use it."""
        t = self.doc.frame
        img = self.doc.render.frames.get(t)
        if img is None:
            self.win.statusBar().showMessage(f"Frame {t} is not rendered yet: render it first or load an image.", 5000)
            return False
        folder = reference_folder(self.doc.project_path)
        path = folder / f"rendered_frame_{t:06d}_{int(time.time())}.exr"
        try:
            a = img.astype(np.float32)
            write_exr(path, {"R": a[..., 0], "G": a[..., 1], "B": a[..., 2]}, "half")
        except Exception as e:
            self.win.show_error("Cannot write the reference frame", f"{path}:\n{e}")
            return False
        self._set(("reference",), f"Use rendered frame {t} as reference", lambda val: setattr(self.e, "reference", val), self.e.reference, edit_ops.Reference(path=str(path), at=t), "reference")
        return True

    def clear_reference(self) -> None:
        self._set(("reference",), "Clear reference", lambda val: setattr(self.e, "reference", val), self.e.reference, None, "reference")


def reference_folder(project: Path | None) -> Path:
    """Where rendered frames used as references are written (they must outlive the session)."""
    if project is not None:
        return project.parent / (project.name.removesuffix(".json") + ".refs")
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "x2video" / "references"
