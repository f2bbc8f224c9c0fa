"""`x2video dataset make|demo`: generate procedural interior shots (train/test split by room, resumable)."""
from __future__ import annotations

import argparse
import json
import logging
import multiprocessing as mp
import os
import time
from dataclasses import dataclass
from pathlib import Path

from x2video.cycles.outside.dataset import make_outside

log = logging.getLogger(__name__)

DEMO = {"seed": 7, "frames": 33, "width": 320, "height": 224}


def parse_size(text: str) -> tuple[int, int]:
    """'320x224' -> (320, 224), at least 8 pixels each way."""
    from x2video.train.data import parse_size as parse

    w, h = parse(text)
    if w < 8 or h < 8:
        raise ValueError(f"--size {text}: width and height must be at least 8")
    return w, h


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


def is_done(path: Path) -> bool:
    """A room is finished when its shot.json exists (the writer writes it last)."""
    return (path / "shot.json").is_file()


@dataclass
class _Job:
    index: int
    seed: int
    out: str
    frames: int
    width: int
    height: int


_RENDERER = None


def _work(job: _Job) -> tuple[int, float]:
    """Worker: render one room with this process's renderer (one EGL context per process)."""
    global _RENDERER
    from x2video.procedural.renderer import ProceduralRenderer
    from x2video.procedural.shotgen import write_procedural_shot

    if _RENDERER is None or (_RENDERER.width, _RENDERER.height) != (job.width, job.height):
        _RENDERER = ProceduralRenderer(job.width, job.height)
    t0 = time.perf_counter()
    write_procedural_shot(job.out, job.seed, job.frames, job.width, job.height, renderer=_RENDERER, overwrite=True)
    return job.index, time.perf_counter() - t0


def make(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from x2video.io.atomic import write_json_atomic

    width, height = parse_size(args.size)
    if getattr(args, "renderer", "raster") == "cycles":
        from x2video.cycles.dataset import make_cycles

        return make_cycles(args, width, height)
    if args.rooms < 1 or args.frames < 1:
        raise ValueError(f"--rooms and --frames must be at least 1 (got {args.rooms}, {args.frames})")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = {"rooms": args.rooms, "frames": args.frames, "width": width, "height": height, "seed": args.seed, "test_every": args.test_every}
    meta = out / "dataset.json"
    if meta.is_file():
        old = json.loads(meta.read_text())
        clash = {k: (old.get(k), v) for k, v in settings.items() if k != "rooms" and old.get(k) != v}
        if clash:
            raise ValueError(f"{out}: holds a data set made with other settings {clash} (old, new); use another --out")
    write_json_atomic(meta, {**settings, "format": "x2video-procedural-dataset", "complete": False})
    jobs = [_Job(i, room_seed(args.seed, i), str(room_dir(out, i, args.test_every)), args.frames, width, height) for i in range(args.rooms)]
    todo = [j for j in jobs if not is_done(Path(j.out))]
    log.info("%d rooms, %d already done, %d to render with %d worker(s)", len(jobs), len(jobs) - len(todo), len(todo), args.workers)
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), unit="room", desc="rooms")
    t0, frames = time.perf_counter(), 0
    if args.workers <= 1:
        it = map(_work, todo)
    else:
        pool = mp.get_context("spawn").Pool(args.workers)
        it = pool.imap_unordered(_work, todo)
    try:
        for _index, _secs in it:
            frames += args.frames
            bar.update(1)
            bar.set_postfix(fps=f"{frames / (time.perf_counter() - t0):.2f}")
    finally:
        bar.close()
        if args.workers > 1:
            pool.terminate()
    rooms = {"train": [], "test": []}
    for j in jobs:
        rooms[room_split(j.index, args.test_every)].append(os.path.relpath(j.out, out))
    write_json_atomic(meta, {**settings, "format": "x2video-procedural-dataset", "complete": True, "splits": rooms})
    print(f"{len(jobs)} rooms in {out} ({len(rooms['train'])} train, {len(rooms['test'])} test)")
    return 0


def demo(args: argparse.Namespace) -> int:
    from x2video.procedural.shotgen import write_procedural_shot

    out = Path(args.out)
    write_procedural_shot(out, DEMO["seed"], DEMO["frames"], DEMO["width"], DEMO["height"], overwrite=True)
    print(f"demo shot ({DEMO['frames']} frames, {DEMO['width']}x{DEMO['height']}) in {out}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("dataset", help="generate procedural interior shots (training data, demo scene)")
    sub = p.add_subparsers(dest="dataset_command", metavar="ACTION")
    sub.required = True
    m = sub.add_parser("make", help="render N procedural rooms into DIR/train/room_XXXXX and DIR/test/room_XXXXX (resumable)")
    m.add_argument("--rooms", type=int, required=True, help="number of rooms (one shot each)")
    m.add_argument("--frames", type=int, default=60, help="frames per shot")
    m.add_argument("--size", default="320x224", help="WIDTHxHEIGHT in pixels")
    m.add_argument("--seed", type=int, default=0, help="data set seed; room i uses scene seed seed*1000003+i")
    m.add_argument("--out", required=True, help="output folder")
    m.add_argument("--workers", type=int, default=1, help="parallel processes (one EGL context each)")
    m.add_argument("--test-every", type=int, default=10, help="every N-th room goes to the test split (0: no test split)")
    m.add_argument("--renderer", choices=("raster", "cycles"), default="raster",
                   help="raster: the fast moderngl renderer (shot folders); cycles: Blender's path tracer through bpy (Blender"
                        " multi-layer EXR shots with a val split; needs `pip install 'x2video-studio[cycles]'`)")
    m.add_argument("--samples", type=int, default=64, help="cycles: path-tracing samples per pixel (Combined is denoised)")
    m.set_defaults(func=make)
    o = sub.add_parser("outside", help="path-trace the hand-written outside test scenes into DIR/test/<scene> (Cycles, resumable)")
    o.add_argument("--out", required=True, help="output folder")
    o.add_argument("--size", default="320x224", help="WIDTHxHEIGHT in pixels")
    o.add_argument("--frames", type=int, default=12, help="frames per scene")
    o.add_argument("--samples", type=int, default=32, help="path-tracing samples per pixel (Combined is denoised)")
    o.add_argument("--scenes", default="kitchen,corridor,night_mirror", help="comma-separated scenes to render")
    o.set_defaults(func=make_outside)
    d = sub.add_parser("demo", help="write the small demo shot (1 room, 33 frames, 320x224, deterministic)")
    d.add_argument("out", help="output shot folder")
    d.set_defaults(func=demo)
