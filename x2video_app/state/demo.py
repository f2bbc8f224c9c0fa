"""The demo shot a new user sees: `x2video.demo`'s cached room (path-traced with Cycles where bpy is installed, else
the rasterized procedural room), made once, in a subprocess."""
from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Callable

# In a child process (`python -m x2video.demo`, the library's own entry point) so the GUI never blocks on Blender
# or the procedural renderer's GL context, and a crash there cannot take the editor down. It uses the same cache
# as `x2video render --demo` (X2VIDEO_DEMO_DIR overrides it, as there; X2VIDEO_DEMO_RENDERER picks the room).


def _command() -> list[str]:
    # in a frozen bundle sys.executable is the editor itself, which runs a module for `--run-module` (x2video_app.__main__)
    return [sys.executable, "--run-module" if getattr(sys, "frozen", False) else "-m", "x2video.demo"]


def _pump(stream, q: queue.Queue, tag: str) -> None:
    for line in stream:
        q.put((tag, line.rstrip("\n")))
    q.put((tag, None))


def _stop(proc: subprocess.Popen) -> None:
    """Kill the child and what it started (Blender renders in a grandchild): its whole process group."""
    try:
        os.killpg(proc.pid, signal.SIGKILL) if os.name == "posix" else proc.kill()
    except (ProcessLookupError, PermissionError):
        proc.kill()
    proc.wait()


def ensure_demo(poll: Callable[[], None] | None = None, timeout_s: float = 1800.0,
                on_progress: Callable[[int, int, float], None] | None = None,
                on_note: Callable[[str], None] | None = None) -> Path:
    """The demo shot folder, made first if it is not cached. `poll` runs while waiting (GUI event pump),
    `on_progress(done, total, seconds of the last frame)` as Cycles renders each frame, `on_note(line)` with the
    child's warnings (why the demo is the rasterized room)."""
    proc = subprocess.Popen(_command(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1,
                            start_new_session=os.name == "posix")
    q: queue.Queue = queue.Queue()
    for stream, tag in ((proc.stdout, "out"), (proc.stderr, "err")):
        threading.Thread(target=_pump, args=(stream, q, tag), daemon=True, name=f"demo-{tag}").start()
    t0 = time.monotonic()
    folder, err, open_streams = None, [], 2
    try:
        while open_streams or proc.poll() is None:
            if poll is not None:
                poll()
            try:
                tag, line = q.get(timeout=0.05)
            except queue.Empty:
                line, tag = "", ""
            if line is None:
                open_streams -= 1
            elif tag == "out" and line.startswith("DEMO="):
                folder = Path(line[5:])
            elif tag == "out" and line.startswith("progress ") and on_progress is not None:
                done, total, secs = line.split()[1:4]
                on_progress(int(done), int(total), float(secs))
            elif tag == "err" and line:
                err.append(line)
                if line.startswith("WARNING") and on_note is not None:
                    on_note(line.split(": ", 1)[-1])
            if time.monotonic() - t0 > timeout_s:
                raise TimeoutError(f"making the demo shot took longer than {timeout_s:.0f} s")
    except BaseException:
        _stop(proc)
        raise
    proc.wait()
    if proc.returncode != 0 or folder is None or not (folder / "shot.json").is_file():
        raise RuntimeError(f"making the demo shot failed (exit {proc.returncode}):\n" + "\n".join(err)[-2000:])
    return folder
