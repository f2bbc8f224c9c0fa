"""The demo shot a new user sees: the render CLI's cached procedural demo (generated once, in a subprocess)."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

# In a child process so the GUI never blocks on the procedural renderer's GL context and a crash
# there cannot take the editor down. It uses the same cache as `x2video render --demo`.
_SCRIPT = (
    "import sys; from pathlib import Path; from x2video.cli.render import DEMO_CACHE, ensure_demo; "
    "out = sys.argv[1] if len(sys.argv) > 1 else None; "
    "print('DEMO=' + str(ensure_demo(Path(out) if out else DEMO_CACHE)))"
)


def demo_cache_override() -> Path | None:
    """X2VIDEO_DEMO_DIR: a cache folder to use instead of ~/.cache/x2video/demo (tests)."""
    env = os.environ.get("X2VIDEO_DEMO_DIR")
    return Path(env) if env else None


def ensure_demo(poll: Callable[[], None] | None = None, timeout_s: float = 900.0) -> Path:
    """The demo shot folder, generated first if it is not cached; `poll` runs while waiting (GUI event pump)."""
    cmd = [sys.executable, "-c", _SCRIPT]
    override = demo_cache_override()
    if override is not None:
        cmd.append(str(override))
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
