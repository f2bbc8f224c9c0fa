"""A lock file that says a project is open in an editor: `NAME.lock` beside what it guards, holding the pid, host,
the process's start and when it was taken. Qt-free.

A second editor on the same project is told who holds it (`ProjectLocked`) and may take it over on purpose. A lock
whose process is gone (a crash, a SIGKILL, a power cut) is stale and taken over without asking, as is one that
cannot be read. A process that holds a lock and opens the same project again (a second window) holds it still.
"""
from __future__ import annotations

import json
import os
import socket
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from x2video.edits.autosave import process_alive, process_start
from x2video.io.atomic import write_json_atomic


def lock_path(target: str | Path) -> Path:
    """The lock file of `target` (a project file, or an unsaved shot's autosave)."""
    target = Path(target)
    return target.with_name(target.name + ".lock")


@dataclass
class LockInfo:
    pid: int
    host: str
    started: str | None
    since: float
    token: str

    def describe(self) -> str:
        when = time.strftime("%Y-%m-%d %H:%M", time.localtime(self.since)) if self.since else "an unknown time"
        return f"pid {self.pid} on {self.host or 'an unknown host'}, since {when}"

    def alive(self) -> bool:
        """Whether the holder still runs (a holder on another host is taken to: its pid cannot be checked from here)."""
        if self.host != socket.gethostname():
            return True
        return process_alive(self.pid, self.started)


class ProjectLocked(Exception):
    """`target` is open in another editor, described by `info`."""

    def __init__(self, target: Path, info: LockInfo) -> None:
        self.target, self.info = target, info
        super().__init__(f"{target} is open in another X2Video Studio ({info.describe()}; lock file {lock_path(target)})")


def read_lock(path: str | Path) -> LockInfo | None:
    """The lock at `path`, None when there is none or it cannot be read."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
        return LockInfo(pid=int(doc["pid"]), host=str(doc.get("host", "")), started=doc.get("started"), since=float(doc.get("since", 0)),
                        token=str(doc.get("token", "")))
    except (OSError, ValueError, KeyError, TypeError):
        return None


#: locks this process holds: lock file -> how many `ProjectLock`s took it (windows on one project share it)
_HELD: dict[str, int] = {}


class ProjectLock:
    """The lock of one project (`target`): `acquire`, `release`."""

    def __init__(self, target: str | Path) -> None:
        self.target = Path(target)
        self.path = lock_path(self.target)
        self.token = uuid.uuid4().hex
        self.held = False

    def _mine(self) -> dict:
        return {"pid": os.getpid(), "host": socket.gethostname(), "started": process_start(os.getpid()), "since": time.time(),
                "token": self.token, "target": str(self.target)}

    def acquire(self, *, take_over: bool = False) -> str:
        """Take the lock; returns what happened ('new', 'own', 'stale: ...', 'taken over: ...'). `ProjectLocked` when
        a live process of another editor holds it, unless `take_over`."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            pass
        else:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(self._mine(), f)
                f.flush()
                os.fsync(f.fileno())
            self.held = True
            _HELD[str(self.path)] = 1
            return "new"
        info = read_lock(self.path)
        if info is not None and info.host == socket.gethostname() and info.pid == os.getpid():
            self.held = True  # this process holds it already (another window on the same project)
            self.token = info.token
            _HELD[str(self.path)] = _HELD.get(str(self.path), 0) + 1
            return "own"
        if info is None:
            how = "stale: the lock file could not be read"
        elif not info.alive():
            how = f"stale: {info.describe()} is no longer running"
        elif take_over:
            how = f"taken over: from {info.describe()}"
        else:
            raise ProjectLocked(self.target, info)
        write_json_atomic(self.path, self._mine(), indent=None)
        now = read_lock(self.path)  # two takers at once: the last rename wins, the other is told
        if now is None or now.token != self.token:
            raise ProjectLocked(self.target, now or LockInfo(0, "", None, 0, ""))
        self.held = True
        _HELD[str(self.path)] = 1
        return how

    def release(self) -> None:
        """Remove the lock if it is still ours (a taken-over lock is left to its new holder)."""
        if not self.held:
            return
        self.held = False
        left = _HELD.get(str(self.path), 1) - 1
        if left > 0:
            _HELD[str(self.path)] = left
            return
        _HELD.pop(str(self.path), None)
        info = read_lock(self.path)
        if info is not None and info.token == self.token and info.pid == os.getpid():
            self.path.unlink(missing_ok=True)
