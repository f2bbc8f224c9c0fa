"""Throughput of `x2video farm` on a local Ray cluster with 1 and 2 workers (one CPU each, one torch thread per
task): the same procedural shots rendered by each cluster size into a fresh output folder.

    python -m bench.farm [--workers 1 2] [--shots 4] [--frames 17] [--size 160x112] [--preset fast] [--quality diffusion]
    python -m bench.farm --shots 1 --frames 256 --quality auto --chunk-frames 64 --out bench/results/farm/long_tier1.json

The second form is one long shot split across the workers (tier 1 in frame chunks; `--quality diffusion` splits it
into its windows instead); `--no-split` renders each shot as one task.

Per cluster size, twice: 'cold' (a fresh cluster: each worker loads the model once, inside the time) and 'warm'
(the same shots again into another folder: the workers keep their model, as on a farm that renders a long
sequence): seconds from submitting the shots to the last done marker, frames per second and shots per minute
over it, each shot's own seconds (its done marker), and the time Ray took to start (not counted). The machine and
its load average are recorded: on a shared machine the speed-up from a second worker is what the other jobs
leave of the second core.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from bench.common import command, results_path
from x2video.cli.args import size_arg
from x2video.fields import add_fields, from_args
from x2video.render.settings import RenderSettings


def _tasks(out: Path, name: str) -> dict:
    """A split shot's tasks (chunks or windows): the worker process and seconds of each (its last start)."""
    from x2video.farm import state

    s = state.read_status(out, name)
    return {t: {"pid": (starts[-1] if starts else {}).get("pid"), "seconds": (s.get("task_seconds") or {}).get(t)}
            for t, starts in (s.get("task_starts") or {}).items()}


def measure(args: argparse.Namespace) -> dict:
    import ray

    from x2video.eval.machine import machine_info
    from x2video.farm import find_jobs, run_farm
    from x2video.procedural.shotgen import write_procedural_shot
    from x2video.weights import ModelOptions

    settings = from_args(RenderSettings, args, base="off")  # the tiers' throughput, not the shot's own frames
    w, h = args.size
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for i in range(args.shots):
            write_procedural_shot(root / "shots" / f"room_{i:02d}", 100 + i, args.shot_frames, w, h)
        jobs = find_jobs([root / "shots"])
        for workers in args.workers:
            t0 = time.perf_counter()
            ray.init(num_cpus=workers, object_store_memory=80 * 1024**2, include_dashboard=False, log_to_driver=False)
            ray_start = time.perf_counter() - t0
            try:
                for phase in ("cold", "warm"):  # warm: the same shots again, the workers have their model loaded
                    t1 = time.perf_counter()
                    result = run_farm(jobs, root / f"out_{workers}_{phase}", settings, ModelOptions(), write=lambda s: None,
                                      chunk_frames=args.chunk_frames, split=args.split)
                    wall = time.perf_counter() - t1
                    if not result.ok:
                        raise RuntimeError(f"farm with {workers} worker(s) failed: {result.failed}")
                    frames = sum(m["frames"] for m in result.done.values())
                    row = {"workers": workers, "phase": phase, "shots": len(result.done), "frames": frames, "wall_seconds": round(wall, 2),
                           "frames_per_second": round(frames / wall, 3), "shots_per_minute": round(60 * len(result.done) / wall, 3),
                           "shot_seconds": {n: m["seconds"] for n, m in sorted(result.done.items())}, "ray_start_seconds": round(ray_start, 2),
                           "tasks": {n: _tasks(root / f"out_{workers}_{phase}", n) for n in sorted(result.done)},
                           "load_average": [round(v, 2) for v in os.getloadavg()]}
                    runs.append(row)
                    print(f"{workers} worker(s), {phase}: {len(result.done)} shots, {frames} frames in {wall:.1f} s = "
                          f"{row['frames_per_second']:.2f} frames/s, {row['shots_per_minute']:.2f} shots/min (Ray started in {ray_start:.1f} s, "
                          f"load average {row['load_average'][0]})", flush=True)
            finally:
                ray.shutdown()
    out = {"format": "x2video-farm-throughput", "command": command("farm"), "machine": machine_info("cpu"),
           "shots": {"count": args.shots, "frames": args.shot_frames, "size": [w, h], "kind": "procedural rooms"},
           "settings": {k: v for k, v in vars(settings).items() if v != getattr(RenderSettings(), k)},
           "split": {"on": args.split, "chunk_frames": args.chunk_frames}, "runs": runs}
    for phase in ("cold", "warm"):
        rows = [r for r in runs if r["phase"] == phase]
        if len(rows) >= 2:
            out[f"speedup_{phase}"] = round(rows[0]["wall_seconds"] / rows[-1]["wall_seconds"], 3)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.farm", description=__doc__.split("\n\n")[0])
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="cluster sizes to measure (default: 1 2)")
    p.add_argument("--shots", type=int, default=4, help="procedural shots (default 4)")
    p.add_argument("--frames", dest="shot_frames", type=int, default=17, help="frames per shot (default 17)")
    p.add_argument("--size", type=size_arg, default=(160, 112), help="WxH (default 160x112, the model's training size)")
    p.add_argument("--chunk-frames", type=int, default=64, help="frames per task for tiers 0 and 1 (default 64)")
    p.add_argument("--no-split", dest="split", action="store_false", help="one task per shot (default: chunks or windows)")
    p.add_argument("--out", type=Path, default=results_path("farm"), help="result JSON (default bench/results/farm/farm.json)")
    add_fields(p.add_argument_group("sampling"), RenderSettings, only=("preset", "quality", "seed"),
               defaults=RenderSettings(preset="fast", quality="diffusion"))
    args = p.parse_args(argv)
    from x2video.io.atomic import write_json_atomic

    result = measure(args)
    write_json_atomic(args.out, result)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
