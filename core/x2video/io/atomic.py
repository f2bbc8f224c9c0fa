"""Atomic file writes: write to a temporary file in the destination folder, then `os.replace` it.

A crash (or an exception) mid-write leaves no half-written file under the final name; the
temporary file keeps the final extension so format-sniffing writers (OpenImageIO, PyAV) pick
the right format.
"""
from __future__ import annotations

import contextlib
import json
import os
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
