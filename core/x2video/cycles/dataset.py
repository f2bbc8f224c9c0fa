"""`x2video dataset make --renderer cycles`: procedural rooms path-traced with Cycles as clips, one Blender process per worker.

Each worker process imports `bpy` once and renders whole rooms (`x2video.cycles.shot.write_room_clips`) with one
thread: the room is built once and `--clips` clips of `--frames` consecutive frames along smooth camera paths
are rendered from it (the paper's InteriorVideo is video too), so scene set-up is paid once per room, not per
frame. Rooms are split train / val / test (never frames or clips; test and validation rooms get one clip at the
paper's 0.05 m per frame); finished frames and clips are skipped, so an interrupted build resumes where it
stopped. `--minutes` budgets a build: no room starts after it, the rooms in flight finish. Without `--out` the
set lives in a cache folder keyed by generator version, seed, size and samples (`default_out`), so a later
session on the same machine reuses it. The build records frames per hour, CPU seconds and the set's variety
(`variety_summary`) in DATA/dataset.json.
"""
from __future__ import annotations

import argparse
import json
import logging
import multiprocessing as mp
import os
import resource
import time
from dataclasses import dataclass, field
from pathlib import Path

from x2video.procedural.dataset import RoomJob

log = logging.getLogger(__name__)

FORMAT = "x2video-cycles-dataset"
#: camera metres per frame in training rooms (test and validation rooms: the paper's 0.05)
TRAIN_SPEED = 0.1
#: light moods (`x2video.procedural.lighting.MOODS`) by the kind of light a user would name
LIGHT_KIND = {"cool daylight": "day", "sunny afternoon": "day", "overcast": "day", "night": "night",
              "warm evening": "mixed", "blue hour": "mixed", "dim": "lamp-only"}


def require_bpy() -> None:
    """Raise a clear error when Blender's Python module is missing."""
    try:
        import importlib.util

        if importlib.util.find_spec("bpy") is None:
            raise ImportError
    except (ImportError, ValueError):
        raise SystemExit("--renderer cycles needs Blender as a Python module: pip install 'x2video-studio[cycles]'"
                         " (bpy 4.2 LTS, Python 3.11)") from None


def default_out(seed: int, width: int, height: int, samples: int, version: int) -> Path:
    """The cache folder of a Cycles data set: $X2VIDEO_DATA_CACHE (default ~/.cache/x2video/datasets)/cycles-v<version>-s<seed>-<W>x<H>-<spp>spp."""
    root = Path(os.environ.get("X2VIDEO_DATA_CACHE") or Path.home() / ".cache" / "x2video" / "datasets")
    return root / f"cycles-v{version}-s{seed}-{width}x{height}-{samples}spp"


@dataclass
class CyclesJob(RoomJob):
    samples: int
    #: camera metres per frame: test rooms move as the paper's paths do (0.05), training rooms faster, for more views
    speed: float = 0.05
    #: the room's clip folders (`out` is the first)
    outs: list[str] = field(default_factory=list)
    version: int = 3
    #: time.time() after which the worker skips the room (0: no budget)
    deadline: float = 0.0


def _quiet() -> None:
    """Pool initializer: Blender prints a progress line per tile and pass to the C stdout; send it to /dev/null."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)


def _work(job: CyclesJob) -> tuple[int, float, int, float]:
    """Worker: one room's clips (imports bpy in this process on first use). Returns (index, seconds, frames rendered,
    CPU seconds); frames 0 when the budget had run out before the room started."""
    if job.deadline and time.time() > job.deadline:
        return job.index, 0.0, 0, 0.0
    from x2video.cycles.shot import CyclesConfig, write_room_clips
    from x2video.procedural.camera import PathConfig

    t0, c0 = time.perf_counter(), time.process_time()
    n = [0]
    write_room_clips(job.outs or [job.out], job.seed, job.frames, job.width, job.height, cfg=CyclesConfig(samples=job.samples, threads=1),
                     path_cfg=PathConfig(speed=job.speed), version=job.version, progress=lambda t, s: n.__setitem__(0, n[0] + 1))
    return job.index, time.perf_counter() - t0, n[0], time.process_time() - c0


def clip_dirs(room: Path, clips: int) -> list[Path]:
    """The shot folders of a room's clips: the room's own folder, then room_XXXXX_c1, _c2, ..."""
    return [room] + [room.with_name(f"{room.name}_c{c}") for c in range(1, clips)]


def variety_summary(shot_dirs: list[Path]) -> dict:
    """Fractions of rooms (clips of one room count once) by light kind and by what their surfaces hold, from shot.json."""
    rooms: dict[int, dict] = {}
    for d in shot_dirs:
        f = d / "shot.json"
        if f.is_file():
            extra = json.loads(f.read_text()).get("extra", {})
            rooms.setdefault(int(extra.get("room_seed", hash(str(d)))), extra)
    n = max(len(rooms), 1)
    light: dict[str, int] = {}
    has: dict[str, int] = {k: 0 for k in ("window", "mirror", "large mirror", "glass", "metal", "glossy floor", "textures", "bump",
                                          "decor (not boxes)", "bevelled furniture", "backdrop")}
    for extra in rooms.values():
        kind = LIGHT_KIND.get(str(extra.get("light_mood")), "other")
        light[kind] = light.get(kind, 0) + 1
        pt = extra.get("path_traced", {}) or {}
        var = pt.get("variety") or {}
        cls = set((extra.get("material_class") or {}).values())
        has["mirror"] += bool(pt.get("mirror"))
        has["large mirror"] += bool(pt.get("mirror") and var.get("large_mirror"))
        has["glass"] += bool(pt.get("glass") or pt.get("glass_objects") or "glass" in cls)
        has["metal"] += bool(pt.get("metal") or "metal" in cls)
        has["glossy floor"] += pt.get("glossy_floor") is not None
        has["textures"] += bool(var.get("surfaces"))
        has["bump"] += bool(var.get("surfaces"))  # every procedural surface drives the bump too
        has["decor (not boxes)"] += bool(var.get("decor"))
        has["bevelled furniture"] += bool(var.get("bevel"))
        has["backdrop"] += bool(var.get("backdrops"))
        has["window"] += bool(pt.get("windows"))
    return {"rooms": len(rooms), "light": {k: round(v / n, 3) for k, v in sorted(light.items())},
            "rooms_with": {k: round(v / n, 3) for k, v in has.items()}}


def finished_rooms(jobs: list[CyclesJob], out: Path, test_every: int) -> tuple[dict[str, list[str]], list[Path]]:
    """({split: finished clip folders relative to `out`}, their paths) over `jobs`, in room order: what dataset.json
    lists. Given every room of the set, a build of some splits (`--splits val`) keeps the others' rooms listed."""
    from x2video.procedural.dataset import is_done, room_split

    rooms: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    done: list[Path] = []
    for j in sorted(jobs, key=lambda j: j.index):
        for o in j.outs:
            if is_done(Path(o)):
                rooms[room_split(j.index, test_every, True)].append(os.path.relpath(o, out))
                done.append(Path(o))
    return rooms, done


def make_cycles(args: argparse.Namespace, width: int, height: int) -> int:
    from tqdm import tqdm

    from x2video.cycles.variety import GENERATOR_VERSION
    from x2video.io.atomic import write_json_atomic
    from x2video.procedural.dataset import begin_dataset, is_done, room_dir, room_seed, room_split

    require_bpy()
    clips = int(getattr(args, "clips", 1) or 1)
    version = int(getattr(args, "generator", 0) or GENERATOR_VERSION)
    minutes = float(getattr(args, "minutes", 0) or 0)
    if args.rooms < 1 or args.frames < 1 or clips < 1:
        raise ValueError(f"--rooms, --frames and --clips must be at least 1 (got {args.rooms}, {args.frames}, {clips})")
    if minutes < 0:
        raise ValueError(f"--minutes must be 0 (no budget) or more (got {minutes})")
    if version not in (2, 3):
        raise ValueError(f"--generator {version}: this build knows generator versions 2 and 3")
    eval_frames = int(getattr(args, "eval_frames", 0) or args.frames)
    if eval_frames < 1:
        raise ValueError(f"--eval-frames must be at least 1 (got {eval_frames})")
    out = Path(args.out) if args.out else default_out(args.seed, width, height, args.samples, version)
    settings = {"rooms": args.rooms, "frames": args.frames, "eval_frames": eval_frames, "width": width, "height": height, "seed": args.seed,
                "test_every": args.test_every, "samples": args.samples, "renderer": "cycles", "clips": clips, "generator": version}
    old = json.loads((out / "dataset.json").read_text()) if (out / "dataset.json").is_file() else {}
    if old and "generator" not in old:  # a set from before clips and generator versions: one clip of v2 rooms
        old_settings = {**old, "clips": 1, "generator": 2, "eval_frames": old.get("frames")}
        write_json_atomic(out / "dataset.json", old_settings)
    if isinstance(old.get("frames"), dict):  # written by a build that stored the per-split totals over the --frames setting
        train = old.get("splits", {}).get("train") or []
        clip = json.loads((out / train[0] / "shot.json").read_text())["num_frames"] if train else args.frames
        old = {**old, "split_frames": old["frames"], "frames": clip}
        write_json_atomic(out / "dataset.json", old)
    meta = begin_dataset(out, settings, FORMAT, builds=old.get("builds", []))  # a build stopped mid-way keeps the record of those before
    deadline = time.time() + minutes * 60 if minutes else 0.0
    jobs = []
    for i in range(args.rooms):
        split = room_split(i, args.test_every, True)
        room = room_dir(out, i, args.test_every, val=True)
        outs = clip_dirs(room, clips if split == "train" else 1)
        jobs.append(CyclesJob(i, room_seed(args.seed, i), str(room), args.frames if split == "train" else eval_frames, width, height, args.samples,
                              0.05 if split != "train" else TRAIN_SPEED, [str(o) for o in outs], version, deadline))
    # test and validation rooms first: a build stopped early can still be measured
    jobs.sort(key=lambda j: (room_split(j.index, args.test_every, True) == "train", j.index))
    wanted = set(args.splits.split(",")) if getattr(args, "splits", None) else {"train", "val", "test"}
    bad = wanted - {"train", "val", "test"}
    if bad:
        raise ValueError(f"--splits: unknown split(s) {sorted(bad)}; expected train, val, test")
    every_job = jobs  # the set's dataset.json lists the finished rooms of every split, not only those built now
    jobs = [j for j in jobs if room_split(j.index, args.test_every, True) in wanted]
    todo = [j for j in jobs if not all(is_done(Path(o)) for o in j.outs)]
    log.info("%d rooms, %d already done, %d to path-trace with %d worker(s)", len(jobs), len(jobs) - len(todo), len(todo), args.workers)
    print(f"{out}: {len(jobs)} rooms ({clips} clip(s) of {args.frames} frames per training room), {len(jobs) - len(todo)} done,"
          f" {len(todo)} to path-trace with {args.workers} worker(s)" + (f", budget {minutes:g} min" if minutes else ""), flush=True)
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), unit="room", desc="rooms (cycles)")
    t0, frames, cpu = time.perf_counter(), 0, 0.0
    pool = mp.get_context("spawn").Pool(max(1, args.workers), initializer=_quiet, maxtasksperchild=8)
    try:
        for _index, _secs, n, c in pool.imap_unordered(_work, todo):
            frames += n
            cpu += c
            if n:
                bar.update(1)
            hours = (time.perf_counter() - t0) / 3600
            bar.set_postfix(frames=frames, frames_per_hour=f"{frames / max(hours, 1e-9):.0f}")
        pool.close()
        pool.join()
    finally:
        bar.close()
        pool.terminate()
    seconds = time.perf_counter() - t0
    cpu_children = resource.getrusage(resource.RUSAGE_CHILDREN)
    rooms, done_dirs = finished_rooms(every_job, out, args.test_every)
    complete = all(is_done(Path(o)) for j in jobs for o in j.outs)  # the splits asked for
    fph = frames / (seconds / 3600) if seconds > 0 and frames else 0.0
    run = {"date": time.strftime("%Y-%m-%d %H:%M"), "workers": args.workers, "frames": frames, "wall_seconds": round(seconds, 1),
           "cpu_seconds": round(cpu_children.ru_utime + cpu_children.ru_stime, 1), "frames_per_hour": round(fph, 1),
           "minutes_budget": minutes}
    variety = variety_summary(done_dirs)
    total = {s: sum(json.loads((out / r / "shot.json").read_text())["num_frames"] for r in rs) for s, rs in rooms.items()}
    write_json_atomic(meta, {**settings, "format": FORMAT, "complete": complete, "splits": rooms, "split_frames": total, "variety": variety,
                             "builds": old.get("builds", []) + [run],
                             "build_seconds_this_run": round(seconds, 1), "frames_this_run": frames})
    print(f"{len(jobs)} rooms in {out} ({len(rooms['train'])} train, {len(rooms['val'])} val, {len(rooms['test'])} test clips;"
          f" frames {total}); {frames} frames path-traced in {seconds:.0f} s ({run['cpu_seconds']:.0f} CPU s) with {args.workers}"
          f" worker(s): {fph:.0f} frames/h" + ("" if complete else "; incomplete (budget): the same command resumes"))
    print("variety (fractions of rooms): " + json.dumps(variety))
    return 0
