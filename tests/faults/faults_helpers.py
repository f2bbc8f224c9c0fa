"""Helpers of the fault suite: tiny shots, a size-limited folder, digests of Edits, checks that a folder holds no
half-written file."""
from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import subprocess
from pathlib import Path

import numpy as np

from x2video.io import write_shot_folder
from x2video.shot import ArrayShot

#: CLI flags that keep a render cheap: the formula tier needs no model
FORMULA = ["--quality", "formula"]


def tiny_arrays(frames: int = 4, h: int = 24, w: int = 32, seed: int = 0) -> dict[str, np.ndarray]:
    """Noisy albedo (so EXRs do not compress to nothing), flat normals, smooth irradiance."""
    rng = np.random.default_rng(seed)
    albedo = rng.uniform(0.05, 0.95, (frames, h, w, 3)).astype(np.float32)
    normal = np.zeros((frames, h, w, 3), np.float32)
    normal[..., 2] = 1
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    irr = np.stack([0.4 + 0.5 * np.exp(-((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / (0.2 * w * w))] * 3, -1)
    return {"albedo": albedo, "normal": normal, "irradiance": np.repeat(irr[None], frames, 0).astype(np.float32)}


def tiny_shot_dir(path: Path, frames: int = 4, h: int = 24, w: int = 32, seed: int = 0, **overrides: np.ndarray) -> Path:
    arrays = {**tiny_arrays(frames, h, w, seed), **overrides}
    return write_shot_folder(ArrayShot({k: v for k, v in arrays.items() if v is not None}), path)


def assert_no_partial_files(folder: Path, *, temporaries_ok: bool = False, recursive: bool = True) -> None:
    """Every file below `folder` under a final name reads whole (images, arrays, JSON), and no temporary of an atomic
    write is left (`temporaries_ok`: a SIGKILLed writer may leave its hidden temporary, never a final name)."""
    from x2video.io.image import read_image

    if not folder.exists():
        return
    for p in folder.rglob("*") if recursive else folder.iterdir():
        if p.is_dir():
            continue
        if ".tmp." in p.name:
            assert temporaries_ok and p.name.startswith("."), f"temporary file left: {p}"
            continue
        if p.suffix == ".exr":
            read_image(p)  # raises on a truncated or damaged file
        elif p.suffix == ".npy":
            a = np.load(p)
            assert a.ndim == 3, p
        elif p.suffix == ".json" and p.name != "journal":
            json.loads(p.read_text())
        elif p.suffix == ".npz":
            with np.load(p) as z:
                [z[k] for k in z.files]


def edits_digest(edits) -> str:
    """What an Edits holds, as a short digest (its description and every painted array)."""
    h = hashlib.sha1(json.dumps(edits.to_dict(), sort_keys=True).encode())
    for name, frames in sorted(edits.mask_arrays().items()):
        for t, a in sorted(frames.items()):
            h.update(f"{name}/{t}".encode())
            h.update(np.ascontiguousarray(a, np.float32).tobytes())
    return h.hexdigest()[:12]


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


class SmallDisk:
    """A folder with `size` bytes of room: a tmpfs mounted there when this process may mount (root; CI containers
    often may not), else a simulated one: the writes `x2video.io.image._write` and the atomic file writes make raise
    ENOSPC once `size` bytes were written into the folder, and `free_bytes` reports what is left (what a real full
    disk shows). `grow(size)` makes room (a remount, or a bigger budget)."""

    def __init__(self, path: Path, size: int) -> None:
        self.path, self.size = path, size
        path.mkdir(parents=True, exist_ok=True)
        mount = ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)]
        self.real = (os.geteuid() == 0 and not os.environ.get("X2VIDEO_FAULTS_NO_MOUNT")
                     and subprocess.run(mount, capture_output=True).returncode == 0)
        self._patches: contextlib.ExitStack | None = None
        if not self.real:
            self._simulate()

    def used(self) -> int:
        return sum(p.stat().st_size for p in self.path.rglob("*") if p.is_file())

    def _simulate(self) -> None:
        import pytest

        import x2video.io.atomic as atomic
        import x2video.io.image as image

        mp = pytest.MonkeyPatch()
        disk = self
        real_write, real_free = image._write, atomic.free_bytes

        def inside(p) -> bool:
            return Path(p).resolve().is_relative_to(disk.path.resolve())

        def free(folder):
            return max(0, disk.size - disk.used()) if inside(folder) else real_free(folder)

        def write(path, spec, data):
            if inside(path) and disk.used() + data.nbytes // 3 > disk.size:  # a zip-compressed half EXR: about 1/3
                raise image.DiskFullError(Path(path).parent, data.nbytes // 3, what=f"writing {Path(path).name}")
            real_write(path, spec, data)

        real_open = open

        class Guarded:
            def __init__(self, f):
                self._f = f

            def write(self, b):
                if disk.used() + len(b) > disk.size:
                    raise OSError(errno.ENOSPC, "No space left on device")
                return self._f.write(b)

            def __getattr__(self, k):
                return getattr(self._f, k)

            def __enter__(self):
                return self

            def __exit__(self, *a):
                return self._f.__exit__(*a)

        def guarded_open(file, mode="r", *a, **k):
            f = real_open(file, mode, *a, **k)
            return Guarded(f) if ("w" in mode or "a" in mode) and isinstance(file, (str, os.PathLike)) and inside(file) else f

        import x2video.io.writers as writers

        real_close = writers.MP4Writer.close

        def close(w):  # PyAV writes the MP4 itself (C): over budget once encoded, the file goes and ENOSPC is raised
            out = real_close(w)
            if inside(w.path) and disk.used() > disk.size:
                Path(w.path).unlink()
                raise OSError(errno.ENOSPC, "No space left on device")
            return out

        mp.setattr(writers.MP4Writer, "close", close)
        mp.setattr(image, "_write", write)
        mp.setattr(image, "free_bytes", free)
        mp.setattr(atomic, "free_bytes", free)
        import builtins

        mp.setattr(builtins, "open", guarded_open)
        self._mp = mp

    def grow(self, size: int) -> None:
        self.size = size
        if self.real:
            subprocess.run(["mount", "-o", f"remount,size={size}", str(self.path)], check=True)

    def close(self) -> None:
        if self.real:
            subprocess.run(["umount", "-l", str(self.path)], capture_output=True)
        else:
            self._mp.undo()
