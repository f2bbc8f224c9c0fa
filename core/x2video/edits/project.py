"""Project files: a JSON document (shot path, Edits, version) plus one NPZ of painted mask frames per mask.

Layout: ``scene.x2v.json`` and ``scene.x2v.masks/<content hash>.npz`` beside it. Saving writes
new mask files under content-hash names first, then replaces the JSON atomically, then removes
mask files nothing refers to, so a crash at any point leaves the previous or the new project
whole. Loading refuses unknown fields and newer versions with an error naming them.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from x2video.edits.model import Edits
from x2video.io.atomic import write_bytes_atomic, write_json_atomic
from x2video.io.metadata import read_json

PROJECT_FORMAT = "x2video-project"
PROJECT_VERSION = 1
#: the file name ending a project is saved under (loading reads any .json that holds one)
PROJECT_SUFFIX = ".x2v.json"
_FIELDS = {"format", "version", "shot", "edits", "mask_files"}


@dataclass
class Project:
    """A shot (path; absolute after `load_project`) and the Edits made to it."""

    shot: str
    edits: Edits = field(default_factory=Edits)


def masks_dir(path: str | Path) -> Path:
    path = Path(path)
    return path.parent / f"{path.name.removesuffix('.json')}.masks"


def _npz_bytes(frames: dict[int, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **{f"frame_{t:06d}": np.asarray(a, np.float32) for t, a in sorted(frames.items())})
    return buf.getvalue()


def save_project(path: str | Path, project: Project) -> None:
    """Write `project` to `path` (JSON) and its mask arrays beside it, atomically."""
    path = Path(path)
    project.edits.validate()
    mdir = masks_dir(path)
    files: dict[str, str] = {}
    for name, frames in project.edits.mask_arrays().items():
        if not frames:
            continue
        data = _npz_bytes(frames)
        fname = hashlib.sha1(data).hexdigest()[:20] + ".npz"
        target = mdir / fname
        if not target.exists():
            write_bytes_atomic(target, data)
        files[name] = f"{mdir.name}/{fname}"
    shot = Path(project.shot)
    if shot.is_absolute():
        try:
            shot_str = os.path.relpath(shot, path.parent.resolve())
        except ValueError:  # another drive (Windows)
            shot_str = str(shot)
    else:
        shot_str = str(shot)
    doc = {
        "format": PROJECT_FORMAT,
        "version": PROJECT_VERSION,
        "shot": Path(shot_str).as_posix(),
        "edits": project.edits.to_dict(),
        "mask_files": files,
    }
    write_json_atomic(path, doc)
    for p in path.parent.glob(f".{path.stem}.*.tmp{path.suffix}"):  # what a killed save left (one editor per project: the lock)
        p.unlink(missing_ok=True)
    keep = {Path(f).name for f in files.values()}
    if mdir.is_dir():
        for p in mdir.glob("*.npz"):
            if p.name not in keep:
                p.unlink()


def load_project(path: str | Path) -> Project:
    """Read a project file written by `save_project`; the shot path comes back absolute."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: project file does not exist")
    doc = read_json(path)
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a JSON object")
    if doc.get("format") != PROJECT_FORMAT:
        raise ValueError(f"{path}: field 'format' is {doc.get('format')!r}, expected {PROJECT_FORMAT!r}")
    version = doc.get("version")
    if not isinstance(version, int) or version < 1:
        raise ValueError(f"{path}: field 'version' is {version!r}, expected a positive integer")
    if version > PROJECT_VERSION:
        raise ValueError(f"{path}: project version {version} is newer than this x2video reads ({PROJECT_VERSION}); update x2video")
    unknown = set(doc) - _FIELDS
    if unknown:
        raise ValueError(f"{path}: unknown field(s) {', '.join(sorted(unknown))}")
    if not isinstance(doc.get("shot"), str):
        raise ValueError(f"{path}: field 'shot' must be the path of the shot")
    files = doc.get("mask_files", {})
    if not isinstance(files, dict):
        raise ValueError(f"{path}: field 'mask_files' must map mask names to files")
    arrays: dict[str, dict[int, np.ndarray]] = {}
    for name, rel in files.items():
        arrays[name] = _read_masks(path.parent / rel, f"{path}: mask {name!r}")
    try:
        edits = Edits.from_dict(doc.get("edits", {}), arrays)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    shot = Path(doc["shot"])
    if not shot.is_absolute():
        shot = (path.parent / shot).resolve()
    return Project(shot=str(shot), edits=edits)


def is_project_file(path: str | Path) -> bool:
    """Whether `path` is a JSON file that says it is a project (not a shot's shot.json, not anything else)."""
    path = Path(path)
    if not (path.is_file() and path.suffix == ".json" and path.name != "shot.json"):
        return False
    try:
        with open(path, encoding="utf-8") as f:
            head = json.load(f)
    except (OSError, ValueError):
        return False
    return isinstance(head, dict) and head.get("format") == PROJECT_FORMAT


def remove_project(path: str | Path) -> None:
    """Delete a project file and its mask folder (no error when they are gone already)."""
    Path(path).unlink(missing_ok=True)
    shutil.rmtree(masks_dir(path), ignore_errors=True)


def _read_masks(file: Path, where: str) -> dict[int, np.ndarray]:
    if not file.is_file():
        raise ValueError(f"{where}: mask file {file} is missing")
    try:
        with np.load(file, allow_pickle=False) as z:
            out = {}
            for key in z.files:
                if not key.startswith("frame_"):
                    raise ValueError(f"{where}: {file} holds an unexpected array {key!r}")
                out[int(key[6:])] = z[key]
            return out
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"{where}: cannot read mask file {file} ({exc})") from None
