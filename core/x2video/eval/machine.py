"""Machine facts recorded beside every measured time (results.json "machine")."""
from __future__ import annotations

import os
import platform
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


