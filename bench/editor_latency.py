"""Editor latency (issue 31): how soon the editor shows something, measured on its real start-up path.

    xvfb-run -a python -m bench.editor_latency [SHOT] [--renders 3] [--untrained] [--quality auto]

Starts X2Video Studio as `python -m x2video_app` does (`x2video_app._qt.launch.launch`: the demo shot,
the shipped weights built in the background) and measures, on the wall clock:

  startup_to_demo_visible_s   process start -> the viewer painted the shot (the demo by default)
  model_ready_s               process start -> the background model build finished
  prepare_s                   the Render panel set -> the background `Renderer.prepare` of the shot finished (the
                              editor starts it when a shot opens or the settings change: conditioning encoded,
                              the engine's graphs built; nothing for tiers 0/1); presses wait for it, as a person
                              looking at the shot before pressing Render would (--no-wait-prepare: they do not)
  then, with the model built, per press of the Render button (mouse click):
  press_to_frame_on_screen_s  -> the viewer painted a frame (the formula's preview of the frame on screen)
  press_to_first_network_s    -> the viewer painted the render's first frame (a keyframe; tier 1: the first batch)
  render_s                    -> the render finished (--full; by default each render is cancelled once its
                              first frame is on screen, to spare a shared machine)
  gui_tick_gap_ms             while the render runs, the gaps between 10 ms timer ticks of the GUI's event loop
                              (median, 95th percentile, max): how long a click or a repaint waits

--base-fps measures only the live preview of an edit over a shot's path-traced frames (issue 52), without the GUI:
tier 0's and tier 1's differences at 320x224 on an object, on a path-traced frame and on a frame filled from keyframes,
and tier 1's on a small object and the whole frame (bench/editor_latency_base.py; results in
bench/results/editor_latency/editor_latency_base.json).

--drag auto,formula adds the slider-drag scenario (issue 43), once per quality listed, after the renders: with the
rendered view on screen it drags the Exposure slider through --drag-hz values a second for --drag-seconds (a mouse
drag's rate) and releases it; the editor's live preview re-renders the frame on screen as it moves. It records

  preview_fps                 live frames the viewer showed while the slider moved, per second (at most the input rate)
  last_input_to_frame_s       the last value -> the viewer showed the frame made with it
  input_to_frame_s            each frame shown: its value's input -> shown (median, 95th percentile)
  frame_seconds               the worker's time per frame (median, 95th percentile)
  gui_tick_gap_ms             while dragging, as above, and `busy`: min(gap, the process's CPU time in it), the part of each
                              gap this process ran (on a machine loaded by higher-priority work most of a long gap is others')
  requests / frames_rendered / dropped / stale_runs  latest-wins: a request waiting when a newer one came was dropped;
                              stale_runs counts renders of a request that was no longer the newest (0: nothing queued)
  settled_to_full_quality_s   the last value -> its frame at full quality on screen

The first render encodes every frame's conditioning; later ones reuse the Renderer's cache unless
--cold (cleared before each press). --tier1-standin adds an UNTRAINED tier-1 network of the default
architecture beside (links to) the shipped weights, so quality auto runs tier 1 as it will once
residual.safetensors ships (its cost does not depend on its weights); it is prepared in a child process,
outside the measured start-up. The machine is shared: the JSON keeps the load average before and after
and `x2video.eval.machine.machine_info`. Writes bench/results/editor_latency/editor_latency.json
(editor_latency_tier1_standin.json with --tier1-standin; editor_latency_drag.json with --drag and no renders).
"""
from __future__ import annotations

import time

T_IMPORT = time.perf_counter()  # before Qt and the app are imported

import argparse  # noqa: E402
import os  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable  # noqa: E402

from bench.common import command, results_path  # noqa: E402
from bench.editor_latency_base import BASE_TARGET_FPS, base_difference_fps  # noqa: E402

#: the GUI probe's timer interval: while a render runs, the gaps between its ticks (median, 95th percentile, max) say how
#: long a click or a repaint would wait (`gui_tick_gap_ms`; 10 ms when the event loop is free)
TICK_MS = 10
#: issue 31's targets, seconds
TARGETS = {"startup_to_demo_visible_s": 5.0, "press_to_frame_on_screen_s": 0.5, "press_to_first_network_s": 1.5}
#: issue 43's targets for the slider drag at 320x224: preview frames/s by the tier that previews, the last input -> its
#: frame on screen, and the GUI's tick gaps while dragging
DRAG_TARGETS = {"preview_fps": {"residual": 10.0, "formula": 30.0}, "last_input_to_frame_s": 0.15, "gui_tick_gap_p95_ms": 30.0}


def process_age() -> float:
    """Seconds since this process started (Linux /proc), else since this module was imported."""
    try:
        ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        uptime = float(Path("/proc/uptime").read_text().split()[0])
        return uptime - ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return time.perf_counter() - T_IMPORT


STANDIN = """
import sys
from pathlib import Path
from x2video.model.residual import ResidualConfig, ResidualNet, save
from x2video.weights import shipped_weights
src, out = shipped_weights(), Path(sys.argv[1])
for f in src.iterdir():
    (out / f.name).symlink_to(f)
save(ResidualNet(ResidualConfig()), out, {"note": "untrained stand-in (bench.editor_latency --tier1-standin)"})
"""


def tier1_standin(folder: Path) -> None:
    """The shipped weights (links) plus an untrained tier-1 net in `folder`, made by a child process."""
    subprocess.run([sys.executable, "-c", STANDIN, str(folder)], check=True)


def drag_scenario(win, quality: str, seconds: float, hz: float, pump: Callable[[float], None],
                  pump_until: Callable[[Callable[[], bool], str], None]) -> dict:
    """Drag the Exposure slider of `win` (the editor, model built) at `quality` for `seconds` at `hz` values a second,
    release it, wait until the live preview settles; what the viewer showed and when (see the module docstring)."""
    import numpy as np

    from x2video_app.tools.tick_probe import TickProbe

    i = win.render_panel.quality.findData(quality)
    win.render_panel.quality.setCurrentIndex(i)
    win.render_panel.base_check.setChecked(False)  # time the tier itself, not the shot's own frames
    win.doc.set_view("rendered")
    pump_until(lambda: win.render_ctl.prepare_worker is None and win.live.idle, "the editor at rest before the drag")
    live, slider = win.live, win.edit_panel.exposure
    shown: list = []
    on_shown = lambda res: shown.append((time.perf_counter(), res))  # noqa: E731
    live.sigShown.connect(on_shown)
    p = live.previewer
    before = (p.submitted, p.dropped, len(p.taken))
    n = max(2, int(round(seconds * hz)))
    lo, hi = (-2.0, 2.0) if slider.value() > 0 else (2.0, -2.0)  # the first value differs from the one set
    values = [round(lo + (hi - lo) * k / (n - 1), 2) for k in range(n)]
    inputs: list[tuple[float, int]] = []  # (when, the edits' version it made)
    probe = TickProbe(TICK_MS)
    probe.start()
    slider.setSliderDown(True)
    t0 = time.perf_counter()
    for k, v in enumerate(values):
        slider.setValue(v)
        inputs.append((time.perf_counter(), win.doc.version))
        pump(t0 + (k + 1) / hz)
    t_last, v_last = inputs[-1]
    probe.stop()
    slider.setSliderDown(False)
    pump_until(lambda: live.idle and live.shown is not None and live.shown.request.version == win.doc.version, "the live preview to settle")
    pump(time.perf_counter() + 0.1)
    live.sigShown.disconnect(on_shown)
    during = [(at, r) for at, r in shown if inputs[0][0] <= at <= t_last]
    reflect = next((at for at, r in shown if r.request.version >= v_last), None)
    full = next((at for at, r in shown if r.request.version >= v_last and r.request.final), None)  # the sampler's frame
    if full is None and live.shown is not None and live.is_full(live.shown) and reflect is not None:
        full = max(reflect, live.settled_at or reflect)  # a per-frame tier's frame is its full quality once the edits rest
    lat = np.array([at - r.request.asked_at for at, r in shown]) if shown else np.zeros(1)
    secs = np.array([r.frame.seconds for _, r in shown]) if shown else np.zeros(1)
    taken = list(p.taken)[before[2]:]
    tier = shown[-1][1].frame.tier if shown else None
    row = {
        "quality": quality,
        "preview_tier": during[-1][1].frame.tier if during else tier,
        "full_quality_tier": tier,
        "why": shown[-1][1].choice.preview.reason if shown else None,
        "inputs": n, "input_hz": hz, "drag_s": round(t_last - inputs[0][0], 3),
        "frames_shown_while_dragging": len(during),
        "preview_fps": round(len(during) / max(1e-9, t_last - inputs[0][0]), 1),
        "last_input_to_frame_s": None if reflect is None else round(reflect - t_last, 3),
        "settled_to_full_quality_s": None if full is None else round(full - t_last, 3),
        "input_to_frame_s": {"median": round(float(np.median(lat)), 3), "p95": round(float(np.percentile(lat, 95)), 3)},
        "frame_seconds": {"median": round(float(np.median(secs)), 4), "p95": round(float(np.percentile(secs, 95)), 4)},
        "requests": p.submitted - before[0], "frames_rendered": len(taken), "dropped": p.dropped - before[1],
        "stale_runs": sum(rid != newest for rid, newest in taken),
        "gui_tick_gap_ms": probe.summary(),
        "load_average": [round(v, 2) for v in os.getloadavg()],
    }
    want = DRAG_TARGETS["preview_fps"].get(row["preview_tier"])
    row["met"] = {"preview_fps": None if want is None else row["preview_fps"] >= want,
                  "last_input_to_frame_s": reflect is not None and row["last_input_to_frame_s"] <= DRAG_TARGETS["last_input_to_frame_s"],
                  "gui_tick_gap_p95_ms": row["gui_tick_gap_ms"].get("p95", 1e9) <= DRAG_TARGETS["gui_tick_gap_p95_ms"]}
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("shot", nargs="?", help="a shot or project the editor opens (default: the demo shot)")
    ap.add_argument("--renders", type=int, default=3, help="presses of Render, each after the last finished (default 3)")
    ap.add_argument("--quality", default="auto", choices=("auto", "formula", "residual", "diffusion"))
    ap.add_argument("--cold", action="store_true", help="clear the conditioning cache before each press")
    ap.add_argument("--untrained", action="store_true", help="the untrained tiny model instead of the shipped weights")
    ap.add_argument("--tier1-standin", action="store_true", help="add an untrained tier-1 net beside the shipped weights")
    ap.add_argument("--full", action="store_true", help="let each render finish (default: cancel once its first frame shows)")
    ap.add_argument("--preview-frame-only", action="store_true", help="preview only the frame on screen (RenderController.preview_all off)")
    ap.add_argument("--no-wait-prepare", action="store_true", help="press Render without waiting for the shot's background preparation")
    ap.add_argument("--drag", default="", help="the slider-drag scenario at these qualities, comma-separated (e.g. auto,formula)")
    ap.add_argument("--drag-seconds", type=float, default=2.0, help="how long each drag moves the slider (default 2)")
    ap.add_argument("--drag-hz", type=float, default=60.0, help="slider values a second while dragging (default 60, a mouse's rate)")
    ap.add_argument("--base-fps", action="store_true", help="only the live preview of edits over a shot's path-traced frames "
                    "(issue 52: tier 0 and tier 1 differences at 320x224, no GUI); writes editor_latency_base.json")
    ap.add_argument("--note", default="", help="a note kept in the JSON (what else loaded the machine)")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds to wait for any one stage")
    ap.add_argument("--out", type=Path, help="default bench/results/editor_latency/editor_latency[_tier1_standin].json")
    args = ap.parse_args(argv)
    if args.base_fps:
        from x2video.eval.machine import machine_info
        from x2video.io.atomic import write_json_atomic

        out = args.out or results_path("editor_latency", "editor_latency_base")
        rows = base_difference_fps()
        out.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(out, {"format": "x2video-editor-latency-base", "command": command("editor_latency", argv),
                                "machine": machine_info(None), "target_fps": BASE_TARGET_FPS, "rows": rows, "note": args.note})
        print(f"wrote {out}", flush=True)
        return 0
    drags = [q for q in args.drag.split(",") if q]
    name = "editor_latency_tier1_standin" if args.tier1_standin else "editor_latency_drag" if drags and not args.renders else None
    out = args.out or results_path("editor_latency", name)
    started_before_import = process_age() - (time.perf_counter() - T_IMPORT)  # interpreter start -> this module
    tmp = tempfile.TemporaryDirectory(prefix="x2video-latency-")
    if args.tier1_standin:
        tier1_standin(Path(tmp.name))
        os.environ["X2VIDEO_WEIGHTS"] = tmp.name
    t_base = time.perf_counter()  # the measured start-up begins here (plus the interpreter's start)
    load_before = [round(v, 2) for v in os.getloadavg()]

    from PySide6.QtCore import QCoreApplication, QEvent, QEventLoop, QObject, Qt, QTimer
    from PySide6.QtTest import QTest

    from x2video_app._qt.launch import launch
    from x2video_app.state.preview import PreviewReady

    def age() -> float:
        """Seconds of start-up: interpreter start -> this module, then from `t_base` (after any stand-in)."""
        return started_before_import + time.perf_counter() - t_base

    def pump_until(cond: Callable[[], bool], what: str) -> None:
        t_end = time.perf_counter() + args.timeout
        while not cond():
            if time.perf_counter() > t_end:
                raise TimeoutError(f"waited {args.timeout:.0f} s for {what}")
            QCoreApplication.processEvents(QEventLoop.ProcessEventsFlag.AllEvents, 5)
            time.sleep(0.002)

    class PaintWatch(QObject):
        """Records when the viewer paints while `armed` says so."""

        def __init__(self, armed: Callable[[], bool]) -> None:
            super().__init__()
            self.armed, self.at = armed, None

        def eventFilter(self, obj, ev) -> bool:  # noqa: N802 - Qt's name
            if self.at is None and ev.type() == QEvent.Type.Paint and self.armed():
                self.at = age()
            return False

    app, win = launch(([args.shot] if args.shot else []) + (["--untrained"] if args.untrained else []))
    visible = PaintWatch(lambda: win.doc.shot is not None)
    win.viewer.viewport().installEventFilter(visible)
    pump_until(lambda: visible.at is not None or win.errors_shown, "the shot on screen")
    if win.errors_shown:
        raise RuntimeError(f"the editor could not open the shot: {win.errors_shown}")
    demo_visible = visible.at
    pump_until(lambda: win.render_ctl.preload_worker is None and win.render_ctl.renderer is not None, "the model build")
    model_ready = age()
    win.viewer.viewport().removeEventFilter(visible)

    win.render_ctl.preview_all = not args.preview_frame_only
    i = win.render_panel.quality.findData(args.quality)
    t_prepare = time.perf_counter()
    win.render_panel.quality.setCurrentIndex(i)
    win.render_panel.base_check.setChecked(False)  # time the tier itself, not the shot's own frames
    win.rendering.prepare()  # as a changed setting does (also when the quality was already the chosen one)
    if not args.no_wait_prepare:
        pump_until(lambda: win.render_ctl.prepare_worker is None, "the shot's preparation")
    prepare_s = round(time.perf_counter() - t_prepare, 3)
    renders = []
    for k in range(args.renders):
        if args.cold:
            win.render_ctl.renderer.cache.clear()
        marks: dict[str, float] = {}

        def on_event(ev, marks=marks) -> None:  # after the window painted it (connected after the window's slot)
            if isinstance(ev, PreviewReady) and "preview" not in marks:
                marks["preview"] = time.perf_counter()
            elif ev.__class__.__name__ == "FramesReady" and "network" not in marks:
                marks["network"] = time.perf_counter()
                if not args.full:
                    win.render_ctl.cancel()

        win.render_ctl.sigEvent.connect(on_event)
        ticks: list[float] = []
        timer = QTimer()  # the GUI's responsiveness while it renders: gaps between 10 ms ticks of the event loop
        timer.setInterval(TICK_MS)
        timer.timeout.connect(lambda ticks=ticks: ticks.append(time.perf_counter()))
        load = [round(v, 2) for v in os.getloadavg()]
        t_click = time.perf_counter()
        timer.start()
        QTest.mouseClick(win.render_panel.render_button, Qt.MouseButton.LeftButton)
        pump_until(lambda: not win.render_ctl.running and win.render_ctl.preview_worker is None, f"render {k + 1}")
        timer.stop()
        win.render_ctl.sigEvent.disconnect(on_event)
        gaps = sorted(1000 * (b - a) for a, b in zip(ticks, ticks[1:]))
        st, offset = win.doc.render, win.render_ctl.pressed_at - t_click
        row = {
            "press": k + 1,
            "status": st.status,
            "tier": st.tier,
            "reason": st.reason,
            "frames": len(st.frames),
            "windows": st.num_windows,
            "press_to_frame_on_screen_s": None if win.first_frame_shown_s is None else round(offset + win.first_frame_shown_s, 3),
            "press_to_first_network_s": None if win.first_keyframe_shown_s is None else round(offset + win.first_keyframe_shown_s, 3),
            "press_to_first_preview_event_s": round(marks["preview"] - t_click, 3) if "preview" in marks else None,
            "press_to_first_network_event_s": round(marks["network"] - t_click, 3) if "network" in marks else None,
            "render_s": round(st.finished_at - st.started_at, 2) if st.finished_at and st.status == "finished" else None,
            "gui_tick_gap_ms": {"ticks": len(ticks), "median": round(gaps[len(gaps) // 2], 1), "p95": round(gaps[int(0.95 * (len(gaps) - 1))], 1),
                                "max": round(gaps[-1], 1)} if gaps else None,
            "conditioning_cache": str(win.render_ctl.renderer.cache_stats()),
            "engine": getattr(win.render_ctl.renderer, "engine", None),
            "threads": {"torch": win.render_ctl.threads, "engine": getattr(win.render_ctl.renderer.model, "engine_threads", None)},
            "load_average_at_press": load,
        }
        renders.append(row)
        print(f"press {k + 1}: frame on screen {row['press_to_frame_on_screen_s']} s, first network frame "
              f"{row['press_to_first_network_s']} s, render {row['render_s']} s ({row['tier']}: {row['reason']}); GUI tick gaps "
              f"{row['gui_tick_gap_ms']} ms; load {load}", flush=True)

    def pump(until: float) -> None:
        """Run the event loop until `until`, at least once (as between two mouse events, however late they come)."""
        while True:
            QCoreApplication.processEvents(QEventLoop.ProcessEventsFlag.AllEvents, 2)
            if time.perf_counter() >= until:
                return
            time.sleep(0.001)

    drag_rows = []
    for q in drags:
        row = drag_scenario(win, q, args.drag_seconds, args.drag_hz, pump, pump_until)
        drag_rows.append(row)
        print(f"drag at quality {q}: {row['preview_fps']} preview frames/s ({row['preview_tier']}), last input -> frame "
              f"{row['last_input_to_frame_s']} s, full quality ({row['full_quality_tier']}) after {row['settled_to_full_quality_s']} s; "
              f"{row['frames_rendered']} of {row['requests']} requests rendered, {row['stale_runs']} stale; GUI tick gaps "
              f"{row['gui_tick_gap_ms']} ms; load {row['load_average']}", flush=True)

    from x2video.eval.machine import machine_info
    from x2video.io.atomic import write_json_atomic

    first = renders[0] if renders else {}
    summary = {
        "startup_to_demo_visible_s": round(demo_visible, 3),
        "model_ready_s": round(model_ready, 3),
        "prepare_s": None if args.no_wait_prepare else prepare_s,
        "press_to_frame_on_screen_s": first.get("press_to_frame_on_screen_s"),
        "press_to_first_network_s": first.get("press_to_first_network_s"),
    }
    result = {
        "format": "x2video-editor-latency",
        "command": command("editor_latency", argv),
        "machine": machine_info(win.render_ctl.choice.device if win.render_ctl.choice else None),
        "model": win.render_ctl.choice.label if win.render_ctl.choice else None,
        "tier1_standin": args.tier1_standin,
        "preview_all": not args.preview_frame_only,
        "shot": {"frames": win.doc.num_frames, "size": list(win.doc.size[::-1]), "source": "demo" if not args.shot else "argument",
                 "renderer": win.doc.shot.info.extra.get("renderer", "the procedural rasterizer")},  # the demo: Cycles, or the fallback
        "settings": {k: v for k, v in win.render_panel.values().items()},
        "interpreter_start_to_bench_import_s": round(started_before_import, 3),
        "summary (first press; from process start, or from the click)": summary,
        "targets": TARGETS,
        "met": {k: (summary[k] is not None and summary[k] <= v) for k, v in TARGETS.items()},
        "renders": renders,
        "drag_targets": DRAG_TARGETS,
        "drags": drag_rows,
        "note": args.note,
        "load_average_before_after": [load_before, [round(v, 2) for v in os.getloadavg()]],
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out, result)
    print(f"demo visible {summary['startup_to_demo_visible_s']} s after start; model ready {summary['model_ready_s']} s; "
          f"wrote {out}", flush=True)
    win.project.force_dirty = False
    win.undo.setClean()
    win.close()
    app.quit()
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
