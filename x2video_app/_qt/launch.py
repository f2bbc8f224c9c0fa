"""Starting the editor: `python -m x2video_app [--untrained] [SHOT|PROJECT]` builds the QApplication, shows the main
window with its saved geometry, and queues the shot's opening (then the model's build) on the event loop."""
from __future__ import annotations

import logging
import sys

from PySide6.QtCore import QSettings, QTimer
from PySide6.QtWidgets import QApplication

from x2video_app._qt.main_window import APP_NAME, MainWindow
from x2video_app._qt.style import apply_style


def run(argv: list[str]) -> int:
    """Start the editor: `python -m x2video_app [--untrained] [SHOT|PROJECT]` (no path: the demo shot)."""
    app, _win = launch(argv)
    return app.exec()


def launch(argv: list[str]) -> tuple[QApplication, MainWindow]:
    """Build and show the editor for `run`'s arguments, with the shot's opening queued on the event loop (the
    model builds in the background meanwhile); the caller runs the loop (`bench.editor_latency` measures it)."""
    import argparse

    ap = argparse.ArgumentParser(prog="x2video-studio", description="X2Video Studio: edit intrinsic channels, render video.")
    ap.add_argument("path", nargs="?", help="a shot folder/file the loaders read, or a project file (.x2v.json); default: the demo shot")
    ap.add_argument("--untrained", action="store_true", help="use the UNTRAINED tiny model (smoke test) instead of the shipped weights")
    ap.add_argument("--smoke-test", action="store_true", help=argparse.SUPPRESS)  # open, report, quit (packaging checks)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    app = QApplication.instance() or QApplication(sys.argv[:1])
    app.setApplicationName(APP_NAME)
    apply_style(app)
    settings = QSettings("x2video", "studio")
    win = MainWindow(preload=False)
    if settings.value("geometry") is not None:
        win.restoreGeometry(settings.value("geometry"))
    app.aboutToQuit.connect(lambda: settings.setValue("geometry", win.saveGeometry()))
    win.show()

    def build_model() -> None:
        if args.untrained:
            win.act_untrained.setChecked(True)  # builds it too
        else:
            win.render_ctl.preload()

    def start() -> None:
        ok = (not args.smoke_test and win.project.offer_crashed()) or (  # an editor killed before: its autosave first
            win.project.open_path(args.path) if args.path else win.project.open_demo())
        # The model builds in the background once the shot is painted: importing torch in a thread holds
        # the GIL through whole shared-library loads, which stalled opening the demo by seconds here.
        QTimer.singleShot(100, build_model)
        if args.smoke_test:
            print(f"smoke-test: opened={ok} frames={win.doc.num_frames} errors={win.errors_shown}", flush=True)
            win.render_ctl.wait(120_000)
            win.undo.setClean()
            win.close()
            app.exit(0 if ok else 1)

    QTimer.singleShot(0, start)
    return app, win
