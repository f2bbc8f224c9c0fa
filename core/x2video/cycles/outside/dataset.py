"""`x2video dataset outside`: render the outside scenes into DIR/test/<scene>/, one Blender process per scene, in turn.

Resumable as the procedural build is: a scene whose shot.json exists is skipped, and within a scene
finished frames are skipped. Does not import bpy itself (the worker processes do).
"""
from __future__ import annotations

import argparse
import logging
import multiprocessing as mp
import os
import time
from dataclasses import dataclass
from pathlib import Path

from x2video.cycles.outside import SCENES

log = logging.getLogger(__name__)

FORMAT = "x2video-outside-dataset"


@dataclass
class OutsideJob:
    scene: str
    out: str
    frames: int
    width: int
    height: int
    samples: int
    threads: int = 1


def _work(job: OutsideJob) -> None:
    """Worker process: one scene (imports bpy here; Blender's progress lines go to /dev/null)."""
    from x2video.cycles.dataset import _quiet
    from x2video.cycles.outside.render import write_outside_shot
    from x2video.cycles.shot import CyclesConfig

    _quiet()
    write_outside_shot(job.scene, job.out, job.frames, job.width, job.height, cfg=CyclesConfig(samples=job.samples, threads=job.threads))


def _frames_done(out: str) -> int:
    return len(list(Path(out).glob("frame_*.exr")))


def parse_scenes(text: str) -> list[str]:
    names = [s.strip() for s in text.split(",") if s.strip()]
    bad = [s for s in names if s not in SCENES]
    if bad or not names:
        raise ValueError(f"--scenes {text!r}: choose among {', '.join(SCENES)}")
    return names


def make_outside(args: argparse.Namespace) -> int:
    from x2video.cycles.dataset import require_bpy
    from x2video.fields import parse_size
    from x2video.io.atomic import write_json_atomic
    from x2video.procedural.dataset import begin_dataset, is_done

    require_bpy()
    width, height = parse_size(args.size, 8)
    scenes = parse_scenes(args.scenes)
    if args.frames < 1 or args.samples < 1:
        raise ValueError(f"--frames and --samples must be at least 1 (got {args.frames}, {args.samples})")
    out = Path(args.out)
    settings = {"frames": args.frames, "width": width, "height": height, "samples": args.samples, "renderer": "cycles"}
    meta = begin_dataset(out, settings, FORMAT, growable=(), scenes=scenes)
    # the scenes render one after another, so the one Blender process may use every core (0); the set's pixels do not
    # depend on the thread count, only its seconds do
    threads = int(args.threads or 0) or (os.cpu_count() or 1)
    jobs = [OutsideJob(s, str(out / "test" / s), args.frames, width, height, args.samples, threads) for s in scenes]
    todo = [j for j in jobs if not is_done(Path(j.out))]
    log.info("%d outside scenes, %d already done", len(jobs), len(jobs) - len(todo))
    per_scene = {}
    for job in todo:  # one fresh Blender process per scene, one at a time (a process, not a pool: a pool waits forever
        # on a task whose worker was killed)
        before, t0 = _frames_done(job.out), time.perf_counter()
        proc = mp.get_context("spawn").Process(target=_work, args=(job,), name=f"outside-{job.scene}")
        proc.start()
        proc.join()
        secs, n = time.perf_counter() - t0, _frames_done(job.out) - before
        if proc.exitcode != 0:
            raise RuntimeError(f"{job.scene}: the Blender process exited with {proc.exitcode} after {n} new frame(s);"
                               " run the same command again to resume")
        per_scene[job.scene] = round(secs / max(n, 1), 2)
        print(f"{job.scene}: {n} frame(s) path-traced in {secs:.0f} s ({secs / max(n, 1):.1f} s per frame, set-up included)", flush=True)
    write_json_atomic(meta, {**settings, "format": FORMAT, "scenes": scenes, "complete": True,
                             "splits": {"test": [f"test/{s}" for s in scenes]}, "seconds_per_frame_this_run": per_scene,
                             "threads_this_run": threads})
    print(f"{len(jobs)} outside scene(s) in {out / 'test'}")
    return 0
