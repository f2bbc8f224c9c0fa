"""Drives the real editor on the demo shot and saves a screenshot at each stage of a render (docs/screenshots).

    xvfb-run -s "-screen 0 1600x1000x24" python -m x2video_app.tools.screenshots docs/screenshots [--untrained]

Also prints the seconds from pressing Render to the first keyframe on screen.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np


def _wait(app, cond, timeout: float) -> None:
    t0 = time.monotonic()
    while not cond():
        app.processEvents()
        time.sleep(0.02)
        if time.monotonic() - t0 > timeout:
            raise TimeoutError("the editor did not reach the expected state in time")


def _pump(app, seconds: float) -> None:
    """Run the event loop for `seconds` (a mouse's pace between slider values)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        app.processEvents()
        time.sleep(0.02)


def _settle(app, win, timeout: float) -> None:
    """Wait until nothing the editor started is still at work (a mask being propagated, the live preview, the
    conditioning encoded for the next render, Compare's own frames), then let the window paint."""
    _wait(app, lambda: (win.edits.propagate_worker is None and win.live.idle and win.render_ctl.prepare_worker is None
                        and not win.compare.worker.active and not win.render_ctl.running), timeout)
    _pump(app, 0.5)


def _wall_patch(ids: np.ndarray, objects: dict[int, str]) -> tuple[float, float, float]:
    """(x, y, room) of the visible wall point farthest from anything else, below the ceiling line: where a painted
    patch shows whole."""
    import cv2

    walls = [i for i, c in objects.items() if "wall" in c]
    wall = np.isin(ids, walls).astype(np.uint8)
    wall[[0, -1], :] = wall[:, [0, -1]] = 0  # the frame's edge bounds the patch too
    dist = cv2.distanceTransform(wall, cv2.DIST_L2, 5)
    dist[: ids.shape[0] // 5] = 0
    y, x = np.unravel_index(int(np.argmax(dist)), dist.shape)
    return float(x), float(y), float(dist[y, x])


def _save(win, path: Path, max_kb: int = 290) -> None:
    """Grab the window; a 256-colour palette PNG (Pillow, which diffusers already pulls in) keeps it small."""
    from PySide6.QtCore import Qt
    from PySide6.QtGui import QImage

    img = win.grab().toImage().convertToFormat(QImage.Format.Format_RGB888)
    while True:
        try:
            from PIL import Image

            a = np.frombuffer(img.constBits(), np.uint8).reshape(img.height(), img.bytesPerLine())[:, : 3 * img.width()]
            pil = Image.fromarray(a.reshape(img.height(), img.width(), 3).copy())
            pil.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(path, optimize=True)
        except ImportError:
            img.save(str(path), "PNG", 0)
        if path.stat().st_size <= max_kb * 1024:
            break
        img = img.scaledToWidth(int(img.width() * 0.9), Qt.TransformationMode.SmoothTransformation)
    print(f"{path} {img.width()}x{img.height()} {path.stat().st_size // 1024} KB")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--untrained", action="store_true", help="render with the untrained tiny model even when weights exist")
    ap.add_argument("--timeout", type=float, default=1800.0)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    from PySide6.QtWidgets import QApplication

    from x2video.render.events import FramesReady
    from x2video_app._qt.main_window import MainWindow
    from x2video_app._qt.style import apply_style

    app = QApplication.instance() or QApplication(sys.argv[:1])
    apply_style(app)
    win = MainWindow()
    win.resize(1440, 900)
    win.show()
    t_model, ready = time.perf_counter(), {}
    win.render_ctl.sigPreload.connect(lambda busy: None if busy else ready.setdefault("s", time.perf_counter() - t_model))
    assert win.project.open_demo(), win.errors_shown
    if args.untrained or win.render_ctl.choice is None:
        win.act_untrained.setChecked(True)  # starts building the model in the background
    _pump(app, 1)
    _save(win, args.out / "01_demo_opened.png")

    doc, ed = win.doc, win.edits
    doc.set_frame(8)  # the masks are made on the frame the screenshots show
    ids = doc.shot.channel("ids", doc.frame)[..., 0]
    objects = doc.shot.info.object_captions
    # the largest furniture object in view (not floor/walls/ceiling): fill it by id, give it a local prompt and a colour
    counts = {int(i): int((ids == i).sum()) for i in np.unique(ids) if i > 0}
    furniture = [i for i in counts if not any(w in objects.get(i, "") for w in ("floor", "wall", "ceiling", "window", "door", "light"))]
    target = max(furniture or counts, key=counts.get)
    ys, xs = np.nonzero(ids == target)
    ed.add_mask()
    ed.pick(float(np.median(xs)), float(np.median(ys)))
    ed.set_local_prompt(0, f"{objects.get(target, 'an object')}, glossy dark red lacquer")
    doc.set_edit_global(False)
    ed.set_param("albedo_colour", (0.55, 0.08, 0.06), True)
    ed.set_param("roughness_mode", "set", True)
    ed.set_param("roughness", 0.15, True)
    # a painted patch on the open wall: mask out A|M|R there and ask for concrete, the model fills the material in
    ed.add_mask()
    x, y, room = _wall_patch(ids, objects)
    r = max(4.0, min(12.0, room / 2))
    reach = max(0.0, room - r - 2)
    doc.begin_stroke(x - reach, y - reach / 3, r, False)
    for k in range(1, 13):
        doc.stroke_to(x - reach + 2 * reach * k / 12, y - reach / 3 + 2 * reach / 3 * (k % 2), r, False)
    res = doc.end_stroke()
    if res is not None:
        from x2video_app._qt.commands import PaintCommand

        win.undo.push(PaintCommand(doc, *res))
    ed.set_local_prompt(1, "a wall of rough grey concrete")
    win.mask_panel.mask_out.setChecked(True)
    ed.propagate(1)  # carry the painted wall patch along the shot with optical flow (waited for below)
    doc.set_edit_global(True)
    ed.set_param("exposure", 0.5, True)
    ed.set_global_prompt(doc.shot.info.caption or "a cosy room")
    doc.select_mask(0)
    doc.set_edit_global(False)
    doc.set_view("masks")
    _settle(app, win, args.timeout)
    _save(win, args.out / "02_masks_and_prompts.png")
    doc.set_view("albedo")
    win.docks["Parametric edits"].raise_()
    _settle(app, win, args.timeout)
    _save(win, args.out / "03_live_albedo_edit.png")

    _wait(app, lambda: win.render_ctl.preload_worker is None, args.timeout)
    print(f"model ready {ready.get('s', time.perf_counter() - t_model):.1f} s after Open demo (built in the background while editing)")
    # the live preview mid-drag: the Exposure slider held down and moved, the frame on screen re-rendered by tier 1
    doc.set_edit_global(True)
    doc.set_view("rendered")
    slider = win.edit_panel.exposure
    slider.setSliderDown(True)
    for v in (0.6, 0.8, 1.0, 1.2):
        slider.setValue(v)
        _pump(app, 0.15)
    _wait(app, lambda: win.live.shown is not None, 30)
    _pump(app, 0.3)
    _save(win, args.out / "07_live_preview_drag.png")
    slider.setSliderDown(False)
    slider.setValue(0.5)
    ed.set_param("exposure", 0.5, True)
    doc.set_edit_global(False)
    _settle(app, win, args.timeout)  # Render is pressed with nothing else at work, as the timings assume
    shots: dict[str, bool] = {}
    top = {"level": None}

    def on_event(ev) -> None:
        if isinstance(ev, FramesReady):
            st = doc.render
            top["level"] = st.top_level
            if ev.mode == "key" and "key" not in shots:
                shots["key"] = True
                _save(win, args.out / "04_render_keyframes.png")
            prog = dict((lv, (d, p)) for lv, d, p in st.level_progress())
            lv2 = st.top_level - 1
            if lv2 >= 1 and lv2 != 1 and lv2 in prog and prog[lv2][0] == prog[lv2][1] and "mid" not in shots:
                shots["mid"] = True
                _save(win, args.out / "05_render_level_done.png")
            elif lv2 == 1 and prog.get(1, (0, 1))[0] == 1 and "mid" not in shots:
                shots["mid"] = True
                _save(win, args.out / "05_render_level_done.png")

    win.render_ctl.sigEvent.connect(on_event)
    assert win.start_render()
    _wait(app, lambda: not win.render_ctl.running, args.timeout)
    st = doc.render
    print(f"render {st.status} in {st.finished_at - st.started_at:.1f} s; first keyframe on screen {win.first_keyframe_shown_s:.2f} s after pressing Render")
    doc.set_view("side-by-side")
    doc.set_frame(doc.num_frames // 2)
    win.charts.tabs.setCurrentIndex(0)
    _settle(app, win, args.timeout)
    _save(win, args.out / "06_render_finished_side_by_side.png")
    # Compare: a wipe between the Cycles ground truth and the render, PSNR in the status bar
    from x2video_app._qt.compare import SOURCES
    from x2video_app.state.compare_views import MODES

    doc.set_view("rendered")
    win.compare.a.setCurrentIndex(SOURCES.index("ground truth"))
    win.compare.b.setCurrentIndex(SOURCES.index("rendered"))
    win.compare.mode.setCurrentIndex(MODES.index("wipe"))
    _settle(app, win, args.timeout)
    _save(win, args.out / "08_compare_wipe.png")
    win.compare.mode.setCurrentIndex(MODES.index("off"))
    # a prompt-only change re-renders from cached conditioning latents
    win.render_ctl.sigEvent.disconnect(on_event)
    ed.set_global_prompt("the same room at night, lamps on")
    assert win.start_render()
    _wait(app, lambda: not win.render_ctl.running, args.timeout)
    st = doc.render
    print(f"prompt-only re-render {st.status} in {st.finished_at - st.started_at:.1f} s; first keyframe on screen {win.first_keyframe_shown_s:.2f} s; "
          f"conditioning cache {win.render_ctl.renderer.cache_stats()}")
    # a reference frame: the re-render's middle frame, beside what the live preview makes of the shot with it
    doc.set_frame(doc.num_frames // 2)
    assert ed.use_rendered_reference(), win.errors_shown
    win.docks["Scene"].raise_()
    win.compare.a.setCurrentIndex(SOURCES.index("reference"))
    win.compare.b.setCurrentIndex(SOURCES.index("rendered"))
    win.compare.mode.setCurrentIndex(MODES.index("side by side"))
    _settle(app, win, args.timeout)
    _save(win, args.out / "09_reference_frame.png")
    win.project.force_dirty = False
    win.undo.setClean()
    win.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
