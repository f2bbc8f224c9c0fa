"""Machine facts recorded beside every measured time (results.json "machine")."""
from __future__ import annotations

import os
import platform
import re
import subprocess
from pathlib import Path
from typing import Any


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def git_commit(cwd: str | Path | None = None) -> str | None:
    """HEAD of the repository holding this package ("+dirty" when files differ), or None."""
    here = Path(cwd) if cwd is not None else Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here, capture_output=True, text=True, timeout=10)
        return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def machine_info(device: Any = None) -> dict[str, Any]:
    """CPU, cores, torch/CUDA, the device rendering ran on, Python, OS and the git commit."""
    import torch

    info: dict[str, Any] = {
        "cpu": _cpu_name(),
        "cpu_cores": os.cpu_count(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "os": platform.platform(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "git_commit": git_commit(),
    }
    if device is not None:
        info["device"] = str(device)
    try:
        info["load_average"] = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        pass
    return info


def machine_label(info: dict[str, Any]) -> str:
    """One line: 'NVIDIA H100 (cuda)' or 'Intel Xeon ..., 2 cores (cpu)'."""
    dev = str(info.get("device", "cpu"))
    if dev.startswith("cuda") and info.get("cuda"):
        return f"{info['cuda']} ({dev})"
    return f"{info.get('cpu')}, {info.get('cpu_cores')} cores, torch threads {info.get('torch_threads')} (cpu)"



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
