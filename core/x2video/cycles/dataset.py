"""`x2video dataset make --renderer cycles`: procedural rooms path-traced with Cycles, one Blender process per worker.

Each worker process imports `bpy` once and renders whole rooms (`x2video.cycles.shot.write_room_shot`)
with one thread; rooms are split train / val / test (never frames); finished frames and rooms
are skipped, so an interrupted build resumes where it stopped.
"""
from __future__ import annotations

import argparse
import logging
import multiprocessing as mp
import os
import time
from dataclasses import dataclass
from pathlib import Path

from x2video.procedural.dataset import RoomJob

log = logging.getLogger(__name__)

FORMAT = "x2video-cycles-dataset"
#: camera metres per frame in training and validation rooms (test rooms: the paper's 0.05)
TRAIN_SPEED = 0.2


def require_bpy() -> None:
    """Raise a clear error when Blender's Python module is missing."""
    try:
        import importlib.util

        if importlib.util.find_spec("bpy") is None:
            raise ImportError
    except (ImportError, ValueError):
        raise SystemExit("--renderer cycles needs Blender as a Python module: pip install 'x2video-studio[cycles]'"
                         " (bpy 4.2 LTS, Python 3.11)") from None


@dataclass
class CyclesJob(RoomJob):
    samples: int
    #: camera metres per frame: test rooms move as the paper's paths do (0.05), training rooms faster, for more views
    speed: float = 0.05


def _quiet() -> None:
    """Pool initializer: Blender prints a progress line per tile and pass to the C stdout; send it to /dev/null."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)


def _work(job: CyclesJob) -> tuple[int, float, int]:
    """Worker: one room (imports bpy in this process on first use)."""
    from x2video.cycles.shot import CyclesConfig, write_room_shot
    from x2video.procedural.camera import PathConfig

    t0 = time.perf_counter()
    write_room_shot(job.out, job.seed, job.frames, job.width, job.height, cfg=CyclesConfig(samples=job.samples, threads=1),
                    path_cfg=PathConfig(speed=job.speed))
    return job.index, time.perf_counter() - t0, job.frames


def make_cycles(args: argparse.Namespace, width: int, height: int) -> int:
    from tqdm import tqdm

    from x2video.io.atomic import write_json_atomic
    from x2video.procedural.dataset import begin_dataset, is_done, room_dir, room_seed, room_split

    require_bpy()
    if args.rooms < 1 or args.frames < 1:
        raise ValueError(f"--rooms and --frames must be at least 1 (got {args.rooms}, {args.frames})")
    out = Path(args.out)
    settings = {"rooms": args.rooms, "frames": args.frames, "width": width, "height": height, "seed": args.seed,
                "test_every": args.test_every, "samples": args.samples, "renderer": "cycles"}
    meta = begin_dataset(out, settings, FORMAT)
    jobs = [CyclesJob(i, room_seed(args.seed, i), str(room_dir(out, i, args.test_every, val=True)), args.frames, width, height, args.samples,
                      0.05 if room_split(i, args.test_every, True) == "test" else TRAIN_SPEED)
            for i in range(args.rooms)]
    # test and validation rooms first: a build stopped early can still be measured
    jobs.sort(key=lambda j: (room_split(j.index, args.test_every, True) == "train", j.index))
    wanted = set(args.splits.split(",")) if getattr(args, "splits", None) else {"train", "val", "test"}
    bad = wanted - {"train", "val", "test"}
    if bad:
        raise ValueError(f"--splits: unknown split(s) {sorted(bad)}; expected train, val, test")
    jobs = [j for j in jobs if room_split(j.index, args.test_every, True) in wanted]
    todo = [j for j in jobs if not is_done(Path(j.out))]
    log.info("%d rooms, %d already done, %d to path-trace with %d worker(s)", len(jobs), len(jobs) - len(todo), len(todo), args.workers)
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), unit="room", desc="rooms (cycles)")
    t0, frames = time.perf_counter(), 0
    pool = mp.get_context("spawn").Pool(max(1, args.workers), initializer=_quiet, maxtasksperchild=8)
    try:
        for _index, _secs, n in pool.imap_unordered(_work, todo):
            frames += n
            bar.update(1)
            bar.set_postfix(s_per_frame=f"{(time.perf_counter() - t0) / max(frames, 1):.2f}")
    finally:
        bar.close()
        pool.terminate()
    seconds = time.perf_counter() - t0
    rooms: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    for j in sorted(jobs, key=lambda j: j.index):  # the splits asked for
        rooms[room_split(j.index, args.test_every, True)].append(os.path.relpath(j.out, out))
    write_json_atomic(meta, {**settings, "format": FORMAT, "complete": True, "splits": rooms,
                             "build_seconds_this_run": round(seconds, 1), "frames_this_run": frames})
    print(f"{len(jobs)} rooms in {out} ({len(rooms['train'])} train, {len(rooms['val'])} val, {len(rooms['test'])} test);"
          f" {frames} frames path-traced in {seconds:.0f} s with {args.workers} worker(s)")
    return 0
