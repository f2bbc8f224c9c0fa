"""Procedural data sets: N rooms, one shot each, split into train and test by room (never by frame); resumable
(a room whose shot.json exists is done) and parallel (one process, one EGL context, per worker)."""
from __future__ import annotations

import json
import logging
import multiprocessing as mp
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

log = logging.getLogger(__name__)


def room_seed(seed: int, index: int) -> int:
    """The scene seed of room `index` of a data set made with `--seed seed`."""
    return int(seed) * 1_000_003 + int(index)


def room_split(index: int, test_every: int, val: bool = False) -> str:
    """Rooms are split, never frames: every `test_every`-th room (index % test_every == test_every - 1) is a test
    room; with `val`, the room before it (index % test_every == test_every - 2) is a validation room."""
    if test_every > 0 and index % test_every == test_every - 1:
        return "test"
    if val and test_every > 1 and index % test_every == test_every - 2:
        return "val"
    return "train"


def room_dir(out: Path, index: int, test_every: int, val: bool = False) -> Path:
    return out / room_split(index, test_every, val) / f"room_{index:05d}"


def begin_dataset(out: Path, settings: dict, fmt: str, growable: tuple[str, ...] = ("rooms",), **extra) -> Path:
    """Create `out` and mark OUT/dataset.json incomplete with `settings`; refuse a folder holding a data set made
    with other settings (those in `growable` may change: a build can be resumed with more rooms)."""
    out.mkdir(parents=True, exist_ok=True)
    meta = out / "dataset.json"
    if meta.is_file():
        old = json.loads(meta.read_text())
        clash = {k: (old.get(k), v) for k, v in settings.items() if k not in growable and old.get(k) != v}
        if clash:
            raise ValueError(f"{out}: holds a data set made with other settings {clash} (old, new); use another --out")
    from x2video.io.atomic import write_json_atomic

    write_json_atomic(meta, {**settings, "format": fmt, **extra, "complete": False})
    return meta


def is_done(path: Path) -> bool:
    """A room is finished when its shot.json exists (the writer writes it last)."""
    return (path / "shot.json").is_file()


@dataclass
class RoomJob:
    """One room of a data set for a worker to render: its index, seed, folder, frame count and size."""

    index: int
    seed: int
    out: str
    frames: int
    width: int
    height: int


_RENDERER = None


def _work(job: RoomJob) -> tuple[int, float]:
    """Worker: render one room with this process's renderer (one EGL context per process)."""
    global _RENDERER
    from x2video.procedural.renderer import ProceduralRenderer
    from x2video.procedural.shotgen import write_procedural_shot

    if _RENDERER is None or (_RENDERER.width, _RENDERER.height) != (job.width, job.height):
        _RENDERER = ProceduralRenderer(job.width, job.height)
    t0 = time.perf_counter()
    write_procedural_shot(job.out, job.seed, job.frames, job.width, job.height, renderer=_RENDERER, overwrite=True)
    return job.index, time.perf_counter() - t0


def make_dataset(out: str | Path, rooms: int, frames: int, size: tuple[int, int], *, seed: int = 0, test_every: int = 10,
                 workers: int = 1, on_room: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Render `rooms` procedural rooms of `frames` frames at `size` (W, H) into OUT/train/room_XXXXX and
    OUT/test/room_XXXXX, skipping rooms already done, and return what OUT/dataset.json then holds.
    `on_room(done, total)` runs once with the rooms already done, then after each room rendered. A folder
    holding a data set made with other settings is an error."""
    from x2video.io.atomic import write_json_atomic

    width, height = size
    if rooms < 1 or frames < 1:
        raise ValueError(f"--rooms and --frames must be at least 1 (got {rooms}, {frames})")
    out = Path(out)
    settings = {"rooms": rooms, "frames": frames, "width": width, "height": height, "seed": seed, "test_every": test_every}
    meta = begin_dataset(out, settings, "x2video-procedural-dataset")
    jobs = [RoomJob(i, room_seed(seed, i), str(room_dir(out, i, test_every)), frames, width, height) for i in range(rooms)]
    todo = [j for j in jobs if not is_done(Path(j.out))]
    log.info("%d rooms, %d already done, %d to render with %d worker(s)", len(jobs), len(jobs) - len(todo), len(todo), workers)
    done = len(jobs) - len(todo)
    if on_room is not None:
        on_room(done, len(jobs))
    pool = mp.get_context("spawn").Pool(workers) if workers > 1 else None
    try:
        for _index, _secs in (pool.imap_unordered(_work, todo) if pool is not None else map(_work, todo)):
            done += 1
            if on_room is not None:
                on_room(done, len(jobs))
    finally:
        if pool is not None:
            pool.terminate()
    splits: dict[str, list[str]] = {"train": [], "test": []}
    for j in jobs:
        splits[room_split(j.index, test_every)].append(os.path.relpath(j.out, out))
    doc = {**settings, "format": "x2video-procedural-dataset", "complete": True, "splits": splits}
    write_json_atomic(meta, doc)
    return doc
