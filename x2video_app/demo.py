"""The demo shot a new user sees: generated once with `x2video dataset demo OUT` and cached."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable


def demo_dir() -> Path:
    """X2VIDEO_DEMO_DIR, else ~/.cache/x2video/demo_shot (XDG_CACHE_HOME respected)."""
    env = os.environ.get("X2VIDEO_DEMO_DIR")
    if env:
        return Path(env)
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "x2video" / "demo_shot"


def ensure_demo(out: Path, poll: Callable[[], None] | None = None, timeout_s: float = 900.0) -> Path:
    """Generate the demo shot into `out` unless it is there; `poll` runs while waiting (GUI event pump).

    Runs the project CLI in a subprocess so the GUI process never blocks on the renderer's GL
    context and a crash there cannot take the editor down.
    """
    if (out / "shot.json").exists():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "x2video", "dataset", "demo", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    t0 = time.monotonic()
    while proc.poll() is None:
        if poll is not None:
            poll()
        time.sleep(0.05)
        if time.monotonic() - t0 > timeout_s:
            proc.kill()
            raise TimeoutError(f"`{' '.join(cmd)}` took longer than {timeout_s:.0f} s")
    output = proc.stdout.read() if proc.stdout else ""
    if proc.returncode != 0 or not (out / "shot.json").exists():
        raise RuntimeError(f"`{' '.join(cmd)}` failed (exit {proc.returncode}):\n{output[-2000:]}")
    return out
