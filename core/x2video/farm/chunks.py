"""One shot split into tasks that write into one staged output: frame chunks (tiers 0 and 1 are per frame), or the
windows of a diffusion render (each window a task once the windows that make its reference frames are done).

    OUT/.farm/NAME.frames/            the shot's frames as tasks finish them (EXR: the output's files; MP4: float16 .npy)
    OUT/.farm/NAME.chunks/key.json    what the staged frames were made with (a digest of the job key)
    OUT/.farm/NAME.chunks/A-B.json    a chunk's record: starts (attempt, host, pid), frames done, 'done' once finished
    OUT/.farm/NAME.chunks/wI.json     window I's record, and wI.npz: the RGB latents it made (what later windows read)

Every frame is written atomically under its final name, so a killed task leaves whole frames or none; a task
marked done is never run again (a retry or a later run of the farm skips it). `assemble` moves the staged frames
into place when every task is done (the finishing task then writes the done marker and removes
the task records): the EXR folder is renamed to OUT/NAME, or the MP4 encoded (atomically) from
them exactly as `x2video.FrameSink` encodes a single-process render. Staged frames made with other settings (a
stopped farm run again with other flags) are removed before anything is reused.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import socket
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from x2video.farm import state
from x2video.io.atomic import DIR_MODE, atomic_path, write_json_atomic
from x2video.io.units import OutputUnits
from x2video.render.events import FramesReady

#: frames per task for the per-frame tiers (`x2video farm --chunk-frames`)
CHUNK_FRAMES = 64


def chunk_ranges(start: int, stop: int, size: int) -> list[tuple[int, int]]:
    """[start, stop) cut into ranges of `size` frames (the last one shorter)."""
    if size < 1:
        raise ValueError(f"chunk size must be at least 1 frame, got {size}")
    return [(a, min(a + size, stop)) for a in range(start, stop, size)]


def frames_dir(out: Path, name: str) -> Path:
    return out / ".farm" / f"{name}.frames"


def tasks_dir(out: Path, name: str) -> Path:
    return out / ".farm" / f"{name}.chunks"


def task_path(out: Path, name: str, task: str) -> Path:
    return tasks_dir(out, name) / f"{task}.json"


def chunk_id(a: int, b: int) -> str:
    return f"{a:06d}-{b:06d}"


def window_id(index: int) -> str:
    return f"w{index:04d}"


def latents_path(out: Path, name: str, task: str) -> Path:
    return tasks_dir(out, name) / f"{task}.npz"


def save_latents(out: Path, name: str, task: str, latents: dict[int, np.ndarray]) -> None:
    """A window's RGB latents (frame -> (4, h, w) float32), atomically, so a later run reuses the window."""
    with atomic_path(latents_path(out, name, task)) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **{f"f{k:06d}": np.asarray(v, np.float32) for k, v in latents.items()})


def load_latents(out: Path, name: str, task: str) -> dict[int, np.ndarray] | None:
    """What `save_latents` wrote, None when there is nothing (or nothing readable)."""
    try:
        with np.load(latents_path(out, name, task)) as z:
            return {int(k[1:]): z[k] for k in z.files}
    except (OSError, ValueError):
        return None


def digest(key: dict[str, Any]) -> str:
    """A short digest of a job key (`state.job_key`): staged frames with another digest were made otherwise."""
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:16]


def frame_name(index: int, fmt: state.OutputFormat) -> str:
    return f"{index:06d}.npy" if fmt == "mp4" else f"{index:06d}.exr"


def reset(out: Path, name: str) -> None:
    """Remove the shot's staged frames and task records."""
    shutil.rmtree(frames_dir(out, name), ignore_errors=True)
    shutil.rmtree(tasks_dir(out, name), ignore_errors=True)


def begin(out: Path, name: str, key_digest: str) -> None:
    """Make the staging folders for a render with `key_digest`; what was staged with another digest is removed first."""
    key_file = tasks_dir(out, name) / "key.json"
    try:
        old = state.read_json(key_file)
    except ValueError:
        old = None
    if old is None or old.get("digest") != key_digest:
        reset(out, name)
    frames_dir(out, name).mkdir(parents=True, exist_ok=True)
    tasks_dir(out, name).mkdir(parents=True, exist_ok=True)
    if old is None or old.get("digest") != key_digest:
        write_json_atomic(key_file, {"digest": key_digest})


def read_task(out: Path, name: str, task: str) -> dict[str, Any]:
    try:
        return state.read_json(task_path(out, name, task)) or {}
    except ValueError:
        return {}


def task_done(out: Path, name: str, task: str, key_digest: str, frames: list[int], fmt: state.OutputFormat) -> bool:
    """Whether `task` finished with `key_digest` and every frame it made is staged."""
    rec = read_task(out, name, task)
    if not rec.get("done") or rec.get("digest") != key_digest:
        return False
    folder = frames_dir(out, name)
    return all((folder / frame_name(f, fmt)).is_file() for f in frames)


def start_task(out: Path, name: str, task: str, key_digest: str, run: str) -> int:
    """Record a start of `task` (a chunk or a window stage); returns its attempt number within run `run`."""
    rec = read_task(out, name, task)
    starts = [s for s in rec.get("starts", []) if isinstance(s, dict)]
    attempt = 1 + sum(1 for s in starts if s.get("run") == run)
    starts.append({"run": run, "attempt": attempt, "host": socket.gethostname(), "pid": os.getpid(), "time": time.time()})
    write_json_atomic(task_path(out, name, task), {"digest": key_digest, "starts": starts, "done": False, "frames_done": 0,
                                                  "host": socket.gethostname(), "pid": os.getpid(), "attempt": attempt})
    return attempt


def update_task(out: Path, name: str, task: str, **fields: Any) -> None:
    rec = read_task(out, name, task)
    rec.update(fields, updated=time.time())
    write_json_atomic(task_path(out, name, task), rec)


class StagedFrames:
    """An `on_event` callback that writes each frame of `FramesReady` events into the shot's staging folder, atomically
    under its final name (a frame made again, the seam pass's, replaces the earlier one); `keep` (when given) limits
    it to those frames. `progress(n)` is called with the count of frames written so far."""

    def __init__(self, out: Path, name: str, fmt: state.OutputFormat, units: OutputUnits, keep: set[int] | None = None,
                 progress: Any = None) -> None:
        self.folder, self.fmt, self.units, self.keep, self.progress = frames_dir(out, name), fmt, units, keep, progress
        self.written: set[int] = set()

    def __call__(self, event: Any) -> None:
        if not isinstance(event, FramesReady):
            return
        for index, rgb in event.frames.items():
            if self.keep is None or index in self.keep:
                self.write(index, rgb)
        if self.progress is not None:
            self.progress(len(self.written))

    def write(self, index: int, rgb: np.ndarray) -> None:
        import io

        from x2video.io.atomic import DiskFullError, is_disk_full, looks_full
        from x2video.render.frames import write_exr_frame

        try:
            with atomic_path(self.folder / frame_name(index, self.fmt)) as tmp:
                if self.fmt == "mp4":  # as FrameSink stages an MP4's frames; a Python write, so a full disk raises ENOSPC
                    buf = io.BytesIO()
                    np.save(buf, np.asarray(rgb, dtype=np.float16))
                    with open(tmp, "wb") as f:
                        f.write(buf.getbuffer())
                else:
                    write_exr_frame(tmp, rgb, self.units)
        except OSError as exc:
            if not (is_disk_full(exc) or looks_full(self.folder, np.asarray(rgb).size * 2)):
                raise
            staged = [p.stat().st_size for p in self.folder.iterdir() if p.name[:1].isdigit()]
            each = sum(staged) / len(staged) if staged else np.asarray(rgb).size * 2
            left = len(self.keep - self.written) if self.keep is not None else 1
            raise DiskFullError(self.folder, int(each * left), what=f"staging frame {index}, {left} frame(s) of this task still to write",
                                kept=f"the {len(staged)} frame(s) staged there stay whole and finished tasks are not run again: "
                                     "free space and run the same farm command again to resume") from None
        self.written.add(index)


def assemble(out: Path, name: str, fmt: state.OutputFormat, expected: list[int], units: OutputUnits, fps: float) -> Path:
    """Put the staged frames `expected` in place as the shot's output (see the module docstring); returns its path.
    ValueError naming the staging folder when a frame is missing."""
    folder = frames_dir(out, name)
    missing = [f for f in expected if not (folder / frame_name(f, fmt)).is_file()]
    if missing:
        raise ValueError(f"{folder}: staged frames {missing[:10]} are missing ({len(missing)} of {len(expected)})")
    target = state.output_path(out, name, fmt)
    if fmt == "mp4":
        from x2video.io.writers import MP4Writer

        with MP4Writer(target, fps, encode="srgb") as video:  # atomic, as FrameSink.finish
            for f in expected:
                video.write(units.display(np.load(folder / frame_name(f, fmt)).astype(np.float32)))
    else:
        wanted = {frame_name(f, fmt) for f in expected}
        for p in folder.iterdir():  # what a killed write left (hidden temporaries), frames outside the range
            if p.name not in wanted:
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
        old = None
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=out))
            os.replace(target, old / "previous")
        os.chmod(folder, DIR_MODE)
        os.replace(folder, target)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    return target  # the caller writes the done marker, then `reset`s the task records
