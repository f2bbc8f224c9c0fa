"""Atomic file writes: write to a temporary file in the destination folder, then `os.replace` it.

A crash (or an exception) mid-write leaves no half-written file under the final name; the
temporary file keeps the final extension so format-sniffing writers (OpenImageIO, PyAV) pick
the right format.
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterator


def _umask() -> int:
    old = os.umask(0)
    os.umask(old)
    return old


#: files we create get the usual permissions (mkstemp would leave them 0600)
_FILE_MODE = 0o666 & ~_umask()
#: folders we create with mkdtemp and rename into place get the usual permissions too (mkdtemp makes them 0700)
DIR_MODE = 0o777 & ~_umask()


#: errno values that mean "the folder's device (or the user's quota) is full"
DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)


def format_bytes(n: float) -> str:
    """A byte count for people: 950 B, 12.3 KB, 4.1 MB, 2.0 GB (powers of 1000, as `df -H`)."""
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if abs(n) < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"


def free_bytes(folder: str | Path) -> int | None:
    """Bytes free to this user on the device holding `folder` (its nearest existing parent); None when unknown."""
    p = Path(folder)
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return shutil.disk_usage(p).free
    except OSError:
        return None


class DiskFullError(OSError):
    """No space left where we write: names the folder, the space the write still needs and what is free, and
    what was kept. An OSError with errno ENOSPC, so code that catches OSError still catches it."""

    def __init__(self, folder: str | Path, needed: int | None = None, *, what: str = "the write", kept: str = "",
                 at_most: bool = False) -> None:
        """`needed`: bytes the write still needs (an estimate; `at_most`: an upper bound)."""
        self.folder, self.needed, self.free = Path(folder), needed, free_bytes(folder)
        need = f"{'up to' if at_most else 'about'} {format_bytes(needed)} is needed" if needed else "more space is needed"
        free = f", {format_bytes(self.free)} free" if self.free is not None else ""
        msg = f"no space left in {self.folder} ({what}): {need}{free}"
        if kept:
            msg += f"; {kept}"
        super().__init__(errno.ENOSPC, msg)
        self.what, self.kept = what, kept

    def __str__(self) -> str:  # OSError's str would prefix "[Errno 28]"
        return str(self.strerror)

    def __reduce__(self) -> tuple:  # pickles whole (Ray hands a task's error back to the driver)
        return (_rebuild_disk_full, (str(self.strerror), str(self.folder), self.needed, self.free, self.what, self.kept))


def _rebuild_disk_full(message: str, folder: str, needed: int | None, free: int | None, what: str, kept: str) -> DiskFullError:
    exc = DiskFullError.__new__(DiskFullError)
    OSError.__init__(exc, errno.ENOSPC, message)
    exc.folder, exc.needed, exc.free, exc.what, exc.kept = Path(folder), needed, free, what, kept
    return exc


def is_disk_full(exc: BaseException) -> bool:
    """Whether `exc` says the device or quota is full (errno ENOSPC/EDQUOT, or a `DiskFullError`)."""
    return isinstance(exc, DiskFullError) or (isinstance(exc, OSError) and exc.errno in DISK_FULL_ERRNOS)


def looks_full(folder: str | Path | None, needed: int) -> bool:
    """Whether the device of `folder` has less than `needed` bytes free: how a write error without an errno (numpy's,
    a library's) is told to be a full disk."""
    free = None if folder is None else free_bytes(folder)
    return free is not None and free < needed


def temp_path_for(path: str | Path) -> Path:
    """A fresh, unused temporary path beside `path` that ends with the same suffix."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    return Path(tmp)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write to; on success it replaces `path`, on error it is removed.

    >>> with atomic_path("out/a.exr") as tmp:
    ...     write_something(tmp)
    """
    path = Path(path)
    tmp = temp_path_for(path)
    try:
        yield tmp
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write `data` to `path` atomically (fsync before the rename)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write UTF-8 `text` to `path` atomically."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | Path, obj: Any, indent: int | None = 1) -> None:
    """Write `obj` as JSON to `path` atomically."""
    write_text_atomic(path, json.dumps(obj, indent=indent) + "\n")
