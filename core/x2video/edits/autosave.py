"""Autosave with undo history: what the editor writes beside a project (or, for an unsaved shot, in the cache) so a
crash loses at most the work since the last autosave, and what it reads back on the next start. Qt-free.

    NAME.x2v.autosave.json            the document: the shot, the project it belongs to, the undo history's states
                                      (each an `Edits.to_dict()` plus its painted mask frames by file), the current
                                      state's index and the state the project file holds (clean)
    NAME.x2v.autosave.masks/*.npz     one painted mask frame per file, named by its content's hash, shared by every
                                      state that holds that frame (a stroke adds one frame file, not a copy of all)

Writing: new frame files first (each atomic), then the document atomically (temporary file, fsync, rename), then the
frame files no state refers to any more are removed; a crash at any point leaves the previous autosave or the new one,
whole. Reading a damaged autosave (truncated, not JSON, a mask file missing or corrupt) raises `AutosaveError`, naming
the file and what is wrong; `set_aside` renames it out of the way so it is kept for a person to look at and never
read again. The registry (`note_session`, `crashed_sessions`) lets the next start find the autosaves of sessions
that did not end (their process is gone).
"""
from __future__ import annotations

import copy
import hashlib
import io
import json
import os
import shutil
import socket
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from x2video.edits.model import Edits
from x2video.edits.project import PROJECT_SUFFIX, masks_dir
from x2video.io.atomic import write_bytes_atomic, write_json_atomic

AUTOSAVE_FORMAT = "x2video-autosave"
AUTOSAVE_VERSION = 1
#: the most undo states an autosave keeps (the newest; older undo steps are not recoverable after a crash)
MAX_STATES = 100
_FIELDS = {"format", "version", "shot", "project", "saved", "pid", "host", "states", "index", "clean"}


def autosave_path(project: str | Path | None, shot_path: str | Path | None) -> Path:
    """Where the editor autosaves: beside the project (`scene.x2v.json` -> `scene.x2v.autosave.json`), or for an
    unsaved shot in the cache, under the shot folder's name and a hash of its path (two shots both called 'shot'
    do not share one)."""
    if project is not None:
        project = Path(project)
        return project.with_name(project.stem + ".autosave" + project.suffix)
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "x2video" / "autosave"
    stem = Path(shot_path).name if shot_path else "untitled"
    key = hashlib.sha1(str(Path(shot_path).resolve()).encode()).hexdigest()[:8] if shot_path else "0"
    return cache / f"{stem}-{key}.autosave{PROJECT_SUFFIX}"


class AutosaveError(ValueError):
    """An autosave that cannot be read back: `path` and what is wrong with it (`reason`)."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path, self.reason = Path(path), reason
        super().__init__(f"{path}: {reason}")


@dataclass
class Autosave:
    """The undo history at the last autosave: `states[i]` is the Edits after `i` undo steps from the oldest kept
    (`labels[i]`: the text of the step from state i to i + 1), `index` the state the editor showed, `clean` the state
    the project file holds (None: none of them, or no project file)."""

    shot: str
    states: list[Edits]
    labels: list[str] = field(default_factory=list)
    index: int = 0
    clean: int | None = None
    project: str | None = None
    saved: float = 0.0
    pid: int = 0
    host: str = ""

    @property
    def current(self) -> Edits:
        return self.states[self.index]


def snapshot(edits: Edits) -> Edits:
    """A copy of `edits` that shares its painted mask arrays (which are never modified in place, `x2video.edits.masks`),
    so keeping one per undo step costs the changed frames only."""
    memo = {id(a): a for m in edits.masks.values() for a in m.frames.values()}
    return copy.deepcopy(edits, memo)


def _frame_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, frame=np.asarray(a, np.float32))
    return buf.getvalue()


class _Hashes:
    """Content hash of each mask array, remembered by identity (the arrays are immutable and shared between states)."""

    def __init__(self) -> None:
        self._memo: dict[int, tuple[np.ndarray, str, bytes | None]] = {}

    def name(self, a: np.ndarray) -> tuple[str, bytes]:
        hit = self._memo.get(id(a))
        if hit is not None and hit[0] is a and hit[2] is not None:
            return hit[1], hit[2]
        data = _frame_bytes(a)
        name = hashlib.sha1(data).hexdigest()[:20] + ".npz"
        self._memo[id(a)] = (a, name, data)
        return name, data


def write_autosave(path: str | Path, autosave: Autosave, *, hashes: _Hashes | None = None) -> Path:
    """Write `autosave` to `path` and its mask frames beside it, atomically (see the module docstring)."""
    path = Path(path)
    states, labels, index, clean = autosave.states, list(autosave.labels), autosave.index, autosave.clean
    if not 0 <= index < len(states) or len(labels) != len(states) - 1:
        raise ValueError(f"{path}: autosave index {index} outside its {len(states)} states, or {len(labels)} labels")
    if len(states) > MAX_STATES:  # keep the newest, and always the current one
        first = min(len(states) - MAX_STATES, index)
        states, labels = states[first:first + MAX_STATES], labels[first:first + MAX_STATES - 1]
        index -= first
        clean = None if clean is None or not first <= clean < first + len(states) else clean - first
    hashes = hashes or _Hashes()
    mdir = masks_dir(path)
    docs, used = [], set()
    for k, edits in enumerate(states):
        edits.validate()
        frames: dict[str, dict[str, str]] = {}
        for name, arrays in edits.mask_arrays().items():
            frames[name] = {}
            for t, a in sorted(arrays.items()):
                fname, data = hashes.name(a)
                if fname not in used and not (mdir / fname).exists():
                    write_bytes_atomic(mdir / fname, data)
                used.add(fname)
                frames[name][str(t)] = fname
        docs.append({"label": labels[k - 1] if k else "", "edits": edits.to_dict(), "mask_frames": frames})
    doc = {"format": AUTOSAVE_FORMAT, "version": AUTOSAVE_VERSION, "shot": autosave.shot, "project": autosave.project,
           "saved": time.time(), "pid": os.getpid(), "host": socket.gethostname(), "states": docs, "index": index, "clean": clean}
    write_json_atomic(path, doc, indent=None)
    remove_temporaries(path)
    if mdir.is_dir():
        for p in mdir.iterdir():
            if p.name not in used and (p.suffix == ".npz" or p.name.startswith(".")):
                p.unlink(missing_ok=True)
    return path


def remove_temporaries(path: str | Path) -> None:
    """Delete what killed atomic writes of `path` left beside it (`x2video.io.atomic.temp_path_for`'s names): one
    writer per file (the lock), so a temporary there now is not being written."""
    path = Path(path)
    for p in path.parent.glob(f".{path.stem}.*.tmp{path.suffix}"):
        p.unlink(missing_ok=True)


def is_autosave_file(path: str | Path) -> bool:
    """Whether `path` says it is an autosave of ours (a quick look at its start; a damaged one still counts)."""
    try:
        with open(path, "rb") as f:
            head = f.read(200)
    except OSError:
        return False
    return AUTOSAVE_FORMAT.encode() in head


def read_autosave(path: str | Path) -> Autosave:
    """Read what `write_autosave` wrote; `AutosaveError` naming the file and the fault for anything damaged.
    An autosave of the older kind (a plain project file) reads as a one-state history."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise AutosaveError(path, "the autosave does not exist") from None
    except OSError as exc:
        raise AutosaveError(path, f"cannot be read ({exc.strerror or exc})") from None
    if not raw.strip():
        raise AutosaveError(path, "the file is empty (cut short: written when the disk was full, or the machine stopped)")
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise AutosaveError(path, f"not readable JSON ({exc}); the file is damaged or cut short ({len(raw)} bytes)") from None
    if not isinstance(doc, dict):
        raise AutosaveError(path, "expected a JSON object")
    if doc.get("format") == "x2video-project":  # what the editor autosaved before undo history was kept
        from x2video.edits.project import load_project

        try:
            project = load_project(path)
        except (ValueError, OSError) as exc:
            raise AutosaveError(path, str(exc).removeprefix(f"{path}: ")) from None
        return Autosave(shot=project.shot, states=[project.edits], saved=path.stat().st_mtime)
    if doc.get("format") != AUTOSAVE_FORMAT:
        raise AutosaveError(path, f"field 'format' is {doc.get('format')!r}, expected {AUTOSAVE_FORMAT!r}")
    version = doc.get("version")
    if not isinstance(version, int) or not 1 <= version <= AUTOSAVE_VERSION:
        raise AutosaveError(path, f"field 'version' is {version!r}; this x2video reads autosave version {AUTOSAVE_VERSION}")
    unknown = set(doc) - _FIELDS
    if unknown:
        raise AutosaveError(path, f"unknown field(s) {', '.join(sorted(unknown))}")
    states_doc = doc.get("states")
    if not isinstance(states_doc, list) or not states_doc:
        raise AutosaveError(path, "field 'states' must be a non-empty list")
    index, clean = doc.get("index"), doc.get("clean")
    if not isinstance(index, int) or not 0 <= index < len(states_doc):
        raise AutosaveError(path, f"field 'index' is {index!r}, outside the {len(states_doc)} states")
    if clean is not None and (not isinstance(clean, int) or not 0 <= clean < len(states_doc)):
        raise AutosaveError(path, f"field 'clean' is {clean!r}, outside the {len(states_doc)} states")
    if not isinstance(doc.get("shot"), str):
        raise AutosaveError(path, "field 'shot' must be the path of the shot")
    mdir = masks_dir(path)
    arrays: dict[str, np.ndarray] = {}

    def frame(fname: Any, where: str) -> np.ndarray:
        if not isinstance(fname, str) or "/" in fname or "\\" in fname:
            raise AutosaveError(path, f"{where}: bad mask file name {fname!r}")
        if fname not in arrays:
            file = mdir / fname
            if not file.is_file():
                raise AutosaveError(path, f"{where}: mask file {file} is missing")
            try:
                with np.load(file, allow_pickle=False) as z:
                    arrays[fname] = z["frame"]
            except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
                raise AutosaveError(path, f"{where}: mask file {file} is damaged ({exc})") from None
        return arrays[fname]

    states, labels = [], []
    for k, sd in enumerate(states_doc):
        where = f"states[{k}]"
        if not isinstance(sd, dict) or not isinstance(sd.get("mask_frames", {}), dict):
            raise AutosaveError(path, f"{where}: expected an object with 'edits' and 'mask_frames'")
        masks: dict[str, dict[int, np.ndarray]] = {}
        for name, frames in sd.get("mask_frames", {}).items():
            if not isinstance(frames, dict):
                raise AutosaveError(path, f"{where}.mask_frames[{name!r}]: expected frame -> file")
            try:
                masks[name] = {int(t): frame(f, f"{where}.mask_frames[{name!r}][{t}]") for t, f in frames.items()}
            except ValueError as exc:
                if isinstance(exc, AutosaveError):
                    raise
                raise AutosaveError(path, f"{where}.mask_frames[{name!r}]: frame numbers must be integers") from None
        try:
            states.append(Edits.from_dict(sd.get("edits", {}), masks, where=f"{where}.edits"))
        except ValueError as exc:
            raise AutosaveError(path, str(exc)) from None
        if k:
            labels.append(str(sd.get("label", "")))
    project = doc.get("project")
    return Autosave(shot=doc["shot"], states=states, labels=labels, index=index, clean=clean,
                    project=project if isinstance(project, str) else None, saved=float(doc.get("saved") or 0.0),
                    pid=int(doc.get("pid") or 0), host=str(doc.get("host") or ""))


def set_aside(path: str | Path) -> Path:
    """Rename a damaged autosave (and its mask folder) to `NAME.corrupt-YYYYmmdd-HHMMSS`, out of the editor's way but
    kept; returns the new name of the document."""
    path = Path(path)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    target = path.with_name(f"{path.name}.corrupt-{stamp}")
    n = 1
    while target.exists():
        n += 1
        target = path.with_name(f"{path.name}.corrupt-{stamp}-{n}")
    if path.exists():
        os.replace(path, target)
    mdir = masks_dir(path)
    if mdir.is_dir():
        os.replace(mdir, mdir.with_name(target.name + ".masks"))
    return target


def remove_autosave(path: str | Path) -> None:
    """Delete an autosave and its mask frames (no error when they are gone already)."""
    Path(path).unlink(missing_ok=True)
    shutil.rmtree(masks_dir(path), ignore_errors=True)
    forget_session(path)


# -- the registry of open sessions: which autosaves the next start should offer -----------------------------------------
def registry_dir() -> Path:
    """Where sessions note their autosaves ($XDG_CACHE_HOME/x2video/sessions)."""
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "x2video" / "sessions"


def _entry(path: str | Path) -> Path:
    return registry_dir() / (hashlib.sha1(str(Path(path).resolve()).encode()).hexdigest()[:16] + ".json")


def note_session(path: str | Path, shot: str, project: str | None) -> None:
    """Record that this process autosaves to `path` (the next start offers it if this process dies)."""
    write_json_atomic(_entry(path), {"autosave": str(Path(path).resolve()), "shot": shot, "project": project, "pid": os.getpid(),
                                     "host": socket.gethostname(), "started": process_start(os.getpid()), "time": time.time()})


def forget_session(path: str | Path) -> None:
    _entry(path).unlink(missing_ok=True)


def process_start(pid: int) -> str | None:
    """An id of process `pid`'s start (its start time in clock ticks, Linux /proc), None where unknown: a pid the
    system gave again to another program has another start."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            return f.read().rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return None


def process_alive(pid: int, started: str | None = None) -> bool:
    """Whether process `pid` runs on this machine (and, when `started` is known, is the same process)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # it exists, under another user
    if started is not None:
        now = process_start(pid)
        if now is not None and now != started:
            return False
    return True


def crashed_sessions() -> list[dict[str, Any]]:
    """The registry's entries whose process is gone (on this host) and whose autosave still exists, newest first;
    entries whose autosave is gone are removed."""
    out = []
    folder = registry_dir()
    if not folder.is_dir():
        return out
    for p in folder.glob("*.json"):
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            p.unlink(missing_ok=True)
            continue
        if not isinstance(doc, dict) or not Path(str(doc.get("autosave", ""))).exists():
            p.unlink(missing_ok=True)
            continue
        if doc.get("host") == socket.gethostname() and process_alive(int(doc.get("pid") or 0), doc.get("started")):
            continue
        out.append(doc)
    return sorted(out, key=lambda d: -float(d.get("time") or 0))
