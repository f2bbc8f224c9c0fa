"""`x2video-studio --selftest [SHOT]`: open the editor offscreen, render two frames of the demo shot (or SHOT) with
the model it finds (the shipped weights) and the video diffusion tier, check them, and exit 0, or 1 saying what
failed. For packaging: one command proves a bundle carries Qt and its plugins, torch, the weights, the text
encoder and the procedural renderer (the demo shot is generated on first start)."""
from __future__ import annotations

import os
import sys
import time

#: what the self-test renders: the first two frames, one keyframe window, the fast preset (LCM-2 with the shipped weights)
FRAMES = (0, 2)
TIMEOUT_MS = 600_000
OPEN_TIMEOUT_S = 300


def run(argv: list[str]) -> int:
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    t0 = time.perf_counter()
    import numpy as np
    from PySide6.QtCore import QTimer

    from x2video.render.events import FramesReady
    from x2video.render.settings import RenderSettings
    from x2video_app._qt.launch import launch

    app, win = launch(argv)
    got: dict[int, np.ndarray] = {}
    report: dict[str, object] = {}

    def say(ok: bool, text: str) -> None:
        print(f"selftest: {'ok' if ok else 'FAILED'}: {text} ({time.perf_counter() - t0:.1f} s since start)", flush=True)
        win.undo.setClean()
        win.close()
        app.exit(0 if ok else 1)

    def on_event(ev: object) -> None:
        if isinstance(ev, FramesReady):
            got.update({f: np.asarray(rgb, np.float32) for f, rgb in ev.frames.items()})

    def finished(running: bool) -> None:
        if running:
            return
        st = win.doc.render
        if st.status != "finished":
            say(False, f"render {st.status}: {st.error or win.errors_shown}")
            return
        bad = [f for f in range(*FRAMES) if f not in got or got[f].shape[:2] != win.doc.shot.size or not np.isfinite(got[f]).all()
               or float(got[f].std()) <= 0.0]
        if bad:
            say(False, f"frames {bad} missing, blank or not finite")
            return
        means = ", ".join(f"{float(got[f].mean()):.3f}" for f in sorted(got))
        say(True, f"opened {report['opened']:.1f} s, rendered frames {sorted(got)} ({st.tier}, mean {means}) in "
                  f"{time.perf_counter() - report['start']:.1f} s; model: {win.render_panel.model_label.text()}")

    def start() -> None:  # once the window's own start has opened the shot (the demo is generated on first start)
        if win.doc.shot is None:
            if win.errors_shown or time.perf_counter() - t0 > OPEN_TIMEOUT_S:
                say(False, f"no shot opened: {win.errors_shown or 'timed out'}")
            else:
                QTimer.singleShot(200, start)
            return
        report["opened"] = time.perf_counter() - t0
        win.render_ctl.sigEvent.connect(on_event)
        win.render_ctl.sigRunning.connect(finished)
        report["start"] = time.perf_counter()
        settings = RenderSettings(preset="fast", quality="diffusion", frames=FRAMES, noise="frame", base="off")
        if not win.render_ctl.start(settings):
            say(False, "the render did not start (no model: are the weights missing? " + win.render_panel.model_label.text() + ")")

    QTimer.singleShot(0, start)
    QTimer.singleShot(TIMEOUT_MS, lambda: say(False, f"no result after {TIMEOUT_MS // 1000} s"))
    code = app.exec()
    win.render_ctl.cancel()
    win.render_ctl.wait(60_000)
    return code


if __name__ == "__main__":
    sys.exit(run(sys.argv[1:]))
