"""Export of the rendered frames (MP4, or an EXR sequence with the edited channels if asked) in a worker, with a
progress dialog; reports through a `Host`. The writing is Qt-free: `x2video_app.state.exporter`."""
from __future__ import annotations

import logging
from pathlib import Path

from PySide6.QtCore import QObject
from PySide6.QtWidgets import QCheckBox, QFileDialog, QMessageBox, QProgressDialog, QWidget
from superqt.utils import create_worker

from x2video.io.units import OutputUnits
from x2video.render.settings import RenderSettings
from x2video_app._qt.host import Host
from x2video_app.state import exporter
from x2video_app.state.document import Document

log = logging.getLogger(__name__)


class ExportController(QObject):
    """Exports the Document's rendered frames; `export_worker` is the export in progress (None when none)."""

    def __init__(self, doc: Document, host: Host, parent: QWidget | None = None) -> None:
        """`parent`: the widget the file and progress dialogs sit on."""
        super().__init__(parent)
        self.doc = doc
        self.host = host
        self._dialog_parent = parent
        self.export_worker = None

    def export_dialog(self, kind: str, exposure: float | str = RenderSettings.exposure) -> None:
        """Ask where to export (and, for EXR, whether with the edited channels), then `export`."""
        n, done = self.doc.num_frames, len(self.doc.render.frames)
        if self.doc.shot is None or done < n:
            self.host.show_error("Nothing to export yet", f"{done} of {n} frames are rendered. Render the whole shot first.")
            return
        if kind == "mp4":
            path, _ = QFileDialog.getSaveFileName(self._dialog_parent, "Export MP4", "render.mp4", "MP4 video (*.mp4)")
            with_channels = False
        else:
            path = QFileDialog.getExistingDirectory(self._dialog_parent, "Export EXR sequence into folder")
            box = QMessageBox(QMessageBox.Icon.Question, "EXR export", "Also write the edited intrinsic channels?",
                              QMessageBox.StandardButton.Ok, self._dialog_parent)
            cb = QCheckBox("include edited albedo/normal/roughness/metallic/irradiance")
            box.setCheckBox(cb)
            box.exec()
            with_channels = cb.isChecked()
        if path:
            self.export(kind, Path(path), with_channels, exposure)

    def export(self, kind: str, path: Path, with_channels: bool = False, exposure: float | str = RenderSettings.exposure):
        """Export in a worker with a progress dialog; returns the worker (tests wait on `finished`). `exposure`: the
        MP4's, as the Render settings give it ("auto": the shot's own)."""
        frames = dict(self.doc.render.frames)
        shot, edits, fps = self.doc.shot, self.doc.edits, self.doc.shot.info.fps
        dlg = QProgressDialog(f"Exporting {path.name}…", "Cancel", 0, len(frames), self._dialog_parent)
        dlg.setWindowTitle("Export")
        dlg.setMinimumDuration(300)
        units = OutputUnits.for_shot(shot, exposure)
        log.info("export %s: %s", path, units.describe())
        if kind == "mp4":
            worker = create_worker(exporter.export_mp4, frames, path, fps, units)
        else:
            worker = create_worker(exporter.export_exr, frames, path, shot, edits if with_channels else None, units,
                                   dict(self.doc.render.exact))
        worker.yielded.connect(lambda i: dlg.setValue(i))
        dlg.canceled.connect(worker.quit)

        def failed(e: BaseException) -> None:
            self.host.show_error("Export failed", f"{path}:\n{type(e).__name__}: {e}")

        def finished() -> None:
            dlg.reset()
            dlg.close()
            self.export_worker = None
            if not worker.abort_requested:
                self.host.status(f"Exported {path}", 8000)

        worker.errored.connect(failed)
        worker.finished.connect(finished)
        self.export_worker = worker
        worker.start()
        return worker
