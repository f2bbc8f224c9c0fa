"""The demo shot a new user sees: `x2video.procedural.demo`'s cached procedural room (generated once, in a subprocess)."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

# In a child process (`python -m x2video.procedural.demo`, the library's own entry point) so the GUI
# never blocks on the procedural renderer's GL context and a crash there cannot take the editor down.
# It uses the same cache as `x2video render --demo` (X2VIDEO_DEMO_DIR overrides it, as there).


def ensure_demo(poll: Callable[[], None] | None = None, timeout_s: float = 900.0) -> Path:
    """The demo shot folder, generated first if it is not cached; `poll` runs while waiting (GUI event pump)."""
    # in a frozen bundle sys.executable is the editor itself, which runs a module for `--run-module` (x2video_app.__main__)
    cmd = [sys.executable, "--run-module" if getattr(sys, "frozen", False) else "-m", "x2video.procedural.demo"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    while proc.poll() is None:
        if poll is not None:
            poll()
        time.sleep(0.05)
        if time.monotonic() - t0 > timeout_s:
            proc.kill()
            proc.wait()
            raise TimeoutError(f"making the demo shot took longer than {timeout_s:.0f} s")
    out, err = proc.communicate()
    lines = [ln[5:] for ln in out.splitlines() if ln.startswith("DEMO=")]
    if proc.returncode != 0 or not lines or not (Path(lines[-1]) / "shot.json").is_file():
        raise RuntimeError(f"making the demo shot failed (exit {proc.returncode}):\n{err[-2000:]}")
    return Path(lines[-1])
