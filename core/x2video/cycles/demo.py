"""The path-traced demo room: one room of generator v3 rendered with Cycles once into the demo cache, ground truth kept.

    python -m x2video.cycles.demo FOLDER [--frames N] [--width W] [--height H] [--samples S]   # the render (needs bpy)

The room (`CYCLES_DEMO`) is a test room of the Cycles data sets (no tier-1 net saw it in training, so the editor's
PSNR against it is an honest one) with two windows, a glossy floor that mirrors them and metal furniture (its
shot.json records them under extra.path_traced). The shot is what `x2video dataset make --renderer cycles` writes (a Blender
multi-layer EXR per frame: the passes the loaders read as channels, and Combined, read as `rgb`: the ground truth the
editor's Compare shows as "Cycles" and measures PSNR against). Frames are written atomically and kept, shot.json
last, so an interrupted render resumes.

`ensure_cycles_demo` runs the render in a child process of its own, so Blender's state, threads and per-tile prints
stay out of the caller (the command line holds torch, the editor Qt), and reports each frame. It raises
`CyclesDemoUnavailable` with the reason when bpy is missing or the render fails; `x2video.demo` then falls back to
the rasterized room. Importing this module does not import bpy.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import resource
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

from x2video.fields import add_fields, from_args, to_flags

#: progress(frames done, frames in all, seconds of the last frame); done is 0 while the room is being set up
Progress = Callable[[int, int, float], None]


@dataclass(frozen=True)
class CyclesDemo:
    """Which room, how long, how large and how many samples the demo is rendered at (field docstrings are the help of
    the child's flags, `python -m x2video.cycles.demo --help`)."""

    seed: int = 41000142
    """Room seed: a v3 test room (the cycles-v3-s41 sets' test/room_00019), a study on a sunny afternoon, two windows
    in view and mirrored in a glossy floor (roughness 0.06), sun patches, a copper piece of furniture."""
    frames: int = 33
    """Frames of the shot."""
    width: int = 320
    """Frame width in pixels."""
    height: int = 224
    """Frame height in pixels."""
    samples: int = 16
    """Samples per pixel, OpenImageDenoise'd: what the data sets use (about 3 s a 320x224 frame on a 2-core machine)."""
    version: int = 3
    """Room generator version (the seed names a room of this version)."""
    threads: int = 0
    """Cycles threads (0: every core; the render is the only job when the demo is made)."""

    @property
    def folder_name(self) -> str:
        return f"cycles-v{self.version}-s{self.seed}-{self.frames}f-{self.width}x{self.height}-{self.samples}spp"


CYCLES_DEMO = CyclesDemo()


class CyclesDemoUnavailable(RuntimeError):
    """The path-traced demo cannot be made here; the message says why (bpy missing, the render failed)."""


def bpy_missing() -> str | None:
    """Why Blender's Python module cannot be used here, or None when it is installed."""
    try:
        found = importlib.util.find_spec("bpy") is not None
    except (ImportError, ValueError):
        found = False
    return None if found else "bpy (Blender as a Python module) is not installed: pip install 'x2video-studio[cycles]'"


def _command(folder: Path, spec: CyclesDemo) -> list[str]:
    # in a frozen bundle sys.executable is the editor itself, which runs a module for `--run-module` (x2video_app.__main__)
    run = [sys.executable, "--run-module" if getattr(sys, "frozen", False) else "-m", "x2video.cycles.demo"]
    return run + [str(folder), *to_flags(CyclesDemo, spec, only_changed=False)]


def _last_line(log: Path) -> str:
    try:
        lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    errors = [ln for ln in lines if "Error" in ln or "error" in ln]
    return (errors or lines or [""])[-1][:300]


def ensure_cycles_demo(cache: str | Path, spec: CyclesDemo = CYCLES_DEMO, progress: Progress | None = None) -> Path:
    """The path-traced demo shot's folder under `cache`, rendered first (in a child process; `progress` hears of each
    frame) if it is not there. Raises CyclesDemoUnavailable (with the reason) when bpy is missing, when the render
    fails (the failure is recorded beside the folder, so later calls fall back at once until that file is deleted)
    or when it was stopped."""
    folder = Path(cache) / spec.folder_name
    if (folder / "shot.json").is_file():
        return folder
    failed = folder.with_name(folder.name + ".failed")
    if failed.is_file():
        raise CyclesDemoUnavailable(f"an earlier Cycles render of it failed ({failed.read_text().strip()}); delete {failed} to try again")
    missing = bpy_missing()
    if missing:
        raise CyclesDemoUnavailable(missing)
    folder.mkdir(parents=True, exist_ok=True)
    log = folder.with_name(folder.name + ".log")  # Blender's own output, kept for when it fails
    with open(log, "w") as err:
        proc = subprocess.Popen(_command(folder, spec), stdout=subprocess.PIPE, stderr=err, text=True, bufsize=1)
        try:
            for line in proc.stdout:  # "setup", then "frame T N SECONDS" per frame rendered
                parts = line.split()
                if progress is None or not parts:
                    continue
                if parts[0] == "setup":
                    progress(0, spec.frames, 0.0)
                elif parts[0] == "frame" and len(parts) == 4:
                    progress(int(parts[1]) + 1, int(parts[2]), float(parts[3]))
            rc = proc.wait()
        except BaseException:  # Ctrl-C, or the caller's progress raised: no orphaned Blender keeps rendering
            proc.kill()
            proc.wait()
            raise
    if rc == 0 and (folder / "shot.json").is_file():
        return folder
    if rc < 0:  # killed by a signal: not the render's fault, the next call resumes it
        raise CyclesDemoUnavailable(f"the Cycles render was stopped (signal {-rc}); the next start resumes it")
    why = f"exit {rc}: {_last_line(log)}" if rc else "it ended without writing shot.json"
    from x2video.io.atomic import write_text_atomic

    write_text_atomic(failed, f"{why}; log {log}\n")
    raise CyclesDemoUnavailable(f"the Cycles render failed ({why}); Blender's log is {log}")


def main(argv: list[str] | None = None) -> int:
    """The render itself, in a process of its own: prints "setup" and a "frame T N SECONDS" line per frame on stdout
    (Blender's per-tile prints go to stderr instead), and records wall and CPU seconds in FOLDER/x2video-demo.json."""
    ap = argparse.ArgumentParser(prog="python -m x2video.cycles.demo", description="Render the path-traced demo room with Cycles.")
    ap.add_argument("folder", type=Path)
    add_fields(ap, CyclesDemo)
    args = ap.parse_args(argv)
    spec = from_args(CyclesDemo, args)
    report = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # Blender prints a line per tile and sample to the C stdout: to stderr (the caller's log) with it
    t0, c0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
    print("setup", file=report)
    from x2video.cycles.shot import CyclesConfig, write_room_clips
    from x2video.io.atomic import write_json_atomic

    done = sorted(p.name for p in args.folder.glob("frame_*.exr"))
    secs: list[float] = []

    def frame(t: int, s: float) -> None:
        secs.append(s)
        print(f"frame {t} {spec.frames} {s:.3f}", file=report)

    threads = spec.threads or os.cpu_count() or 1
    write_room_clips([args.folder], spec.seed, spec.frames, spec.width, spec.height, version=spec.version, progress=frame,
                     cfg=CyclesConfig(samples=spec.samples, threads=threads))
    ru = resource.getrusage(resource.RUSAGE_SELF)
    write_json_atomic(args.folder / "x2video-demo.json", {
        "spec": asdict(spec), "threads": threads, "frames_rendered": len(secs), "frames_resumed": len(done),
        "seconds": round(time.perf_counter() - t0, 1), "cpu_seconds": round(ru.ru_utime + ru.ru_stime - c0.ru_utime - c0.ru_stime, 1),
        "render_seconds_per_frame": round(sum(secs) / max(len(secs), 1), 2), "cpus": os.cpu_count()})
    return 0


def describe(folder: Path) -> str:
    """One line on how the demo in `folder` was made ('' when it holds no record)."""
    try:
        rec = json.loads((Path(folder) / "x2video-demo.json").read_text())
    except (OSError, ValueError):
        return ""
    s = rec.get("spec", {})
    return (f"{s.get('frames')} frames at {s.get('width')}x{s.get('height')}, {s.get('samples')} spp, path-traced in "
            f"{rec.get('seconds')} s ({rec.get('cpu_seconds')} CPU s)")


if __name__ == "__main__":
    sys.exit(main())
