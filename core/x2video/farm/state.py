"""A farm's state on the shared output folder, so that a run can be watched from anywhere and resumed.

    OUT/NAME/ or OUT/NAME.mp4      the shot's render (appears only when finished: `x2video.FrameSink` is atomic)
    OUT/NAME.done.json             the done marker, written (atomically) after the render: what made it, when, where
    OUT/.farm/NAME.status.json     progress of the shot's latest start: state, frames, level, attempt, host, pid

A shot whose done marker and output exist is finished: a later run skips it unless its settings differ (an error,
so a finished render is never replaced by accident). Everything here is written with `x2video.io.atomic`.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import socket
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from x2video.farm.jobs import Job
from x2video.io.atomic import write_json_atomic

if TYPE_CHECKING:
    from x2video.render.settings import RenderSettings
    from x2video.weights import ModelOptions

MARKER_FORMAT = "x2video-farm-done"
OutputFormat = Literal["exr", "mp4"]


def output_path(out: Path, name: str, fmt: OutputFormat) -> Path:
    """Where job `name`'s render goes: a folder of EXR frames, or an MP4 file."""
    return out / (f"{name}.mp4" if fmt == "mp4" else name)


def marker_path(out: Path, name: str) -> Path:
    return out / f"{name}.done.json"


def status_path(out: Path, name: str) -> Path:
    return out / ".farm" / f"{name}.status.json"


def _plain(value: Any) -> Any:
    """JSON-ready copy of a settings value (Paths as text, tuples as lists)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def job_key(job: Job, settings: RenderSettings, options: ModelOptions, fmt: OutputFormat, fps: float | None) -> dict[str, Any]:
    """What decides a job's output: its source, the render settings, the model options, the output format."""
    return {"source": str(job.source), "kind": job.kind, "settings": _plain(settings), "model": _plain(options), "format": fmt, "fps": fps}


def read_json(path: Path) -> dict[str, Any] | None:
    """The JSON object in `path`, None when there is none; ValueError naming the file when it is not one."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a JSON object")
    return doc


def finished(out: Path, job: Job, key: dict[str, Any]) -> dict[str, Any] | None:
    """The done marker of a finished `job` (its output exists), None when the job is still to render.

    ValueError naming the marker when the job was finished with other settings (remove it, or render again with --redo)."""
    marker = read_json(marker_path(out, job.name))
    if marker is None:
        return None
    if marker.get("format") != MARKER_FORMAT:
        raise ValueError(f"{marker_path(out, job.name)}: field 'format' is {marker.get('format')!r}, expected {MARKER_FORMAT!r}")
    if marker.get("key") != key:
        theirs = marker.get("key") or {}
        diff = sorted(k for k in set(theirs) | set(key) if theirs.get(k) != key.get(k))
        detail = [f"{k}.{f}" for k in diff if isinstance(key.get(k), dict) and isinstance(theirs.get(k), dict)
                  for f in sorted(set(key[k]) | set(theirs[k])) if key[k].get(f) != theirs[k].get(f)]
        raise ValueError(f"{marker_path(out, job.name)}: this shot was rendered with other {', '.join(detail or diff)}; "
                         "remove the marker (and the output) or pass --redo to render it again")
    if not Path(out / marker.get("output", "")).exists():
        return None  # the output was removed by hand: render again
    return marker


def write_marker(out: Path, job: Job, key: dict[str, Any], output: Path, frames: int, seconds: float, attempt: int) -> dict[str, Any]:
    from x2video import __version__

    marker = {"format": MARKER_FORMAT, "version": 1, "name": job.name, "output": output.name, "frames": frames, "seconds": round(seconds, 3),
              "attempt": attempt, "host": socket.gethostname(), "pid": os.getpid(), "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
              "x2video": __version__, "key": key}
    write_json_atomic(marker_path(out, job.name), marker)
    return marker


def write_status(out: Path, name: str, **fields: Any) -> None:
    """Merge `fields` into the job's status file (one writer at a time: the task that renders it, or the driver)."""
    path = status_path(out, name)
    try:
        doc = read_json(path) or {}
    except ValueError:  # a damaged status file is only progress: start it again
        doc = {}
    doc.update(fields, updated=time.time())
    write_json_atomic(path, doc, indent=None)


def read_status(out: Path, name: str) -> dict[str, Any]:
    try:
        return read_json(status_path(out, name)) or {}
    except ValueError:
        return {}


def start_attempt(out: Path, name: str, run: str) -> int:
    """Record that a worker starts job `name` in run `run`; returns the attempt number within the run (1 = first,
    2 = Ray's retry after the first worker died, ...). Every start is kept in the status file's 'starts'."""
    doc = read_status(out, name)
    starts = [s for s in doc.get("starts", []) if isinstance(s, dict)]
    attempt = 1 + sum(1 for s in starts if s.get("run") == run)
    starts.append({"run": run, "attempt": attempt, "host": socket.gethostname(), "pid": os.getpid(), "time": time.time()})
    write_status(out, name, state="running", run=run, attempt=attempt, host=socket.gethostname(), pid=os.getpid(), starts=starts,
                 frames_done=0, frames_total=None, level=None, error=None, started=time.time())
    return attempt


def remove_leftovers(out: Path, name: str, fmt: OutputFormat) -> list[Path]:
    """Delete what a killed render of `name` left (the sink's staging folder, a half-written temporary MP4); returns them."""
    target = output_path(out, name, fmt)
    found = list(out.glob(f".{target.name}.*.partial")) + list(out.glob(f".{target.stem}.*.tmp{target.suffix}"))
    for p in found:
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                p.unlink()
    return found
