"""Paths as checked-in files record them: repository-relative, or with placeholders for one machine's
folders (DATA/, RUNS/, ~/, TMP/), so that results, logs and commands never name a developer's disk."""
from __future__ import annotations

import os
import re
from pathlib import Path

#: an absolute path inside a text (a command line, a description): not a URL, not a ratio like s/frame
_ABSOLUTE = re.compile(r"(?<![\w.~/:$})\]])/(?:[\w.+-]+/)*[\w.+-]+/?")


def _repository_root() -> Path:
    return Path(__file__).resolve().parents[3]


def portable_path(path: str | Path) -> str:
    """A path as a checked-in file may record it, never one machine's: relative to the current folder or
    the repository when inside them; ~/... inside the home folder; TMP/... inside the temporary folder;
    else, three levels deep or more, the mount point dropped and the next folder named as a placeholder
    (/MOUNT/data/r160 -> DATA/r160, /MOUNT/runs/ship -> RUNS/ship). A relative path is returned as it is."""
    import tempfile

    p = Path(path)
    if not p.is_absolute():
        return p.as_posix()
    p = Path(os.path.normpath(p))
    for base, prefix in ((Path.cwd(), ""), (_repository_root(), ""), (Path.home(), "~/"), (Path(tempfile.gettempdir()), "TMP/")):
        try:
            rest = p.relative_to(Path(os.path.normpath(base))).as_posix()
        except ValueError:
            continue
        if prefix == "~/" and base == Path("/"):
            continue
        return prefix + rest if rest != "." else (prefix.rstrip("/") or ".")
    parts = p.parts[1:]
    if len(parts) >= 3:
        return "/".join([parts[1].upper(), *parts[2:]])
    return p.as_posix()  # /usr/bin and the like: the same on every machine


def scrub_paths(text: str) -> str:
    """`text` with every absolute path in it made portable (`portable_path`)."""
    return _ABSOLUTE.sub(lambda m: portable_path(m.group(0).rstrip("/")) + ("/" if m.group(0).endswith("/") else ""), text)
