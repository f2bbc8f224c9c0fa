"""What a farm renders: one `Job` per shot or project, found in folders of shots/projects or in list files."""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Literal

PROJECT_SUFFIX = ".x2v.json"


@dataclass(frozen=True)
class Job:
    """One shot to render: a shot (any layout `x2video.load_shot` reads) or a project file (its shot and edits)."""

    name: str
    """Output name: the shot folder's (or file's) name, or the project file's name without `.x2v.json`."""
    source: Path
    """Absolute path of the shot or the project file."""
    kind: Literal["shot", "project"]


def job_name(path: Path) -> str:
    """A file-system-safe output name for `path` (project suffix and a shot file's extension dropped)."""
    name = path.name
    if name.endswith(PROJECT_SUFFIX):
        name = name[: -len(PROJECT_SUFFIX)]
    elif path.is_file():
        name = path.stem
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._")
    if not safe:
        raise ValueError(f"{path}: no usable output name in it")
    return safe


def _job(path: Path, where: str) -> Job:
    """The job for one shot or project `path`; ValueError/FileNotFoundError naming `where` when it is neither."""
    from x2video.io.load import detect_format

    path = path.expanduser().resolve()
    if path.name.endswith(PROJECT_SUFFIX):
        if not path.is_file():
            raise FileNotFoundError(f"{where}: project file {path} does not exist")
        return Job(job_name(path), path, "project")
    try:
        detect_format(path)
    except (ValueError, FileNotFoundError) as exc:
        raise type(exc)(f"{where}: {exc}") from None
    return Job(job_name(path), path, "shot")


def _is_shot(path: Path) -> bool:
    from x2video.io.load import detect_format

    try:
        detect_format(path)
    except (ValueError, FileNotFoundError):
        return False
    return True


def read_list(path: Path) -> list[Job]:
    """A list file: one shot or project path per line (relative to the list file's folder); '#' starts a comment."""
    jobs = []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if text:
            entry = Path(text).expanduser()
            jobs.append(_job(entry if entry.is_absolute() else path.parent / entry, f"{path}, line {n}"))
    if not jobs:
        raise ValueError(f"{path}: the list names no shot or project")
    return jobs


def find_jobs(paths: Iterable[str | Path]) -> list[Job]:
    """Jobs for each of `paths`, in order: a shot (a folder or file `x2video.load_shot` reads) or a project file is one
    job; a folder that is not itself a shot gives a job for each shot folder and project file in it (sorted by name);
    any other file is a list file (`read_list`). Two jobs with one output name is an error that names both."""
    jobs: list[Job] = []
    for raw in paths:
        p = Path(raw).expanduser()
        if not p.exists():
            raise FileNotFoundError(f"{p}: no such shot, project, folder or list file")
        if p.name.endswith(PROJECT_SUFFIX) or _is_shot(p):
            jobs.append(_job(p, str(p)))
        elif p.is_dir():
            found = [_job(c, str(c)) for c in sorted(p.iterdir())
                     if not c.name.startswith(".") and (c.name.endswith(PROJECT_SUFFIX) or (c.is_dir() and _is_shot(c)))]
            if not found:
                raise ValueError(f"{p}: neither a shot nor a folder holding shot folders or {PROJECT_SUFFIX} project files")
            jobs += found
        else:
            jobs += read_list(p)
    by_name: dict[str, Job] = {}
    for job in jobs:
        other = by_name.setdefault(job.name, job)
        if other is not job:
            if other.source == job.source:
                raise ValueError(f"{job.source} is listed twice")
            raise ValueError(f"two jobs would write the output {job.name!r}: {other.source} and {job.source} (rename one)")
    return jobs
