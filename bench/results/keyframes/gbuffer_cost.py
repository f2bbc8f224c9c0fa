"""What a G-buffer frame of a keyframe shot costs through the Blender add-on, on a furnished Cycles room.

Builds procedural room SEED (x2video.cycles, as the Cycles factory does), then renders the frames between two
keyframes G-buffer only (packaging/blender/x2video_export/keyframes.py: AOVs, Normal, Depth, IndexOB, Emit + Env,
no bounces, no denoiser, persistent data) several ways and writes wall and CPU seconds per frame:

- ``export``: the add-on's `export_shot` with keyframes at the first and last frame, as a user runs it;
- ``animation_Sspp``: all G-buffer frames in one animation render (what the add-on does), S samples, the light
  tree off (the add-on's choice) or on (Blender's default);
- ``per_frame_1spp``: one render call per frame (as the issue measured it), with and without persistent data.

    PYTHONPATH=core:. python bench/results/keyframes/gbuffer_cost.py [--seed 3] [--frames 17] [--size 320x224]

Needs bpy (the cycles extra). CPU seconds are the Blender process's (all its threads), beside the wall seconds.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

from x2video.fields import parse_size

ROOT = Path(__file__).resolve().parents[3]
ADDON = ROOT / "packaging" / "blender" / "x2video_export"


def load_addon():
    spec = importlib.util.spec_from_file_location("x2video_export", ADDON / "__init__.py", submodule_search_locations=[str(ADDON)])
    mod = importlib.util.module_from_spec(spec)
    sys.modules["x2video_export"] = mod
    spec.loader.exec_module(mod)
    return mod


def summary(costs: list[tuple[float, float]]) -> dict:
    """Mean and median wall / CPU seconds per frame (the mean counts a run's set-up, carried by its first frame)."""
    wall, cpu = [c[0] for c in costs], [c[1] for c in costs]
    return {"frames": len(costs), "wall_mean": statistics.mean(wall), "wall_median": statistics.median(wall),
            "cpu_mean": statistics.mean(cpu), "cpu_median": statistics.median(cpu), "wall_each": wall}


def headline(doc: dict) -> dict:
    """The figure to quote: the add-on's way (one animation render, 1 sample, light tree off, persistent data)."""
    r = doc["runs"]["animation_1spp"]
    return {"what": f"G-buffer frame through the add-on at {doc['size'][0]}x{doc['size'][1]}, 1 sample, no bounces, no denoiser, "
                    "light tree off, persistent data, all frames in one animation render",
            "cpu_seconds_per_frame": r["cpu_mean"], "wall_seconds_per_frame": r["wall_mean"],
            "load_average": doc["machine"].get("load_average"), "threads": doc["threads"],
            "note": quiet_note(doc["machine"].get("load_average"), doc["machine"].get("cpu_cores"))}


def quiet_note(load: list[float] | None, cores: int | None) -> str:
    """How far the wall seconds carry over, from the load the run recorded (its 1-minute average as it ended)."""
    if load and cores and load[0] <= cores:
        return (f"wall seconds with nothing else running (load average {load[0]:.1f} on {cores} cores, this run's own "
                "load); CPU seconds are the figure that carries over to other machines")
    return ("wall seconds on a machine shared with other jobs (load average above its cores): CPU seconds are the "
            "figure that carries over; on an idle machine wall would near CPU / threads")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seed", type=int, default=3, help="procedural room")
    p.add_argument("--frames", type=int, default=11, help="frames of the clip: keyframes are the first and the last")
    p.add_argument("--size", default="320x224")
    p.add_argument("--key-samples", type=int, default=4, help="samples of the two keyframes (their cost is not the point here)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=None, help="default gbuffer_cost.json here (gbuffer_cost_WxH.json at another size "
                   "than 320x224: what bench.keyframes reads at that size)")
    args = p.parse_args(argv)
    w, h = parse_size(args.size)
    if args.out is None:
        from bench.keyframes import gbuffer_cost_path

        args.out = gbuffer_cost_path(f"{w}x{h}")

    import bpy

    from bench.common import clean_json
    from x2video.cycles.room import build_room, extras_for
    from x2video.cycles.shot import CyclesConfig, add_camera, clip_paths, setup_render
    from x2video.eval.machine import machine_info
    from x2video.procedural.scene import generate_scene

    addon = load_addon()
    kf = sys.modules["x2video_export.keyframes"]
    passes = sys.modules["x2video_export.passes"]
    t0 = time.perf_counter()
    desc = generate_scene(args.seed)
    build_room(desc, extras_for(desc, args.seed))
    scene = setup_render(w, h, CyclesConfig(samples=args.key_samples, threads=args.threads))
    add_camera(clip_paths(desc, args.frames, 1, w / h, args.seed, None)[0])
    scene.frame_start, scene.frame_end = 0, args.frames - 1
    build_s = time.perf_counter() - t0
    n_objects = sum(1 for ob in scene.objects if ob.type == "MESH")
    runs: dict[str, dict] = {}
    between = list(range(1, args.frames - 1))
    with tempfile.TemporaryDirectory() as tmp:
        shot = Path(tmp) / "shot"
        addon.export_shot(scene, str(shot), 0, args.frames - 1, keyframe_every=args.frames - 1, report=lambda m: None)
        meta = json.loads((shot / "shot.json").read_text())
        runs["export"] = {"keyframes": meta["keyframes"], "gbuffer_samples": meta["extra"]["gbuffer_samples"],
                          "frame_seconds": meta["extra"]["frame_seconds"]}
        layer = scene.view_layers[0]
        for name, samples, persistent, per_frame, light_tree in (
                ("animation_1spp", 1, True, False, False), ("animation_1spp_light_tree_on", 1, True, False, True),
                ("animation_4spp", 4, True, False, False), ("per_frame_1spp", 1, True, True, False),
                ("per_frame_1spp_no_persistent_data", 1, False, True, False)):
            out = Path(tmp) / name
            out.mkdir()
            with kf.gbuffer_settings(scene, layer, samples):
                scene.render.use_persistent_data = persistent
                if light_tree and hasattr(scene.cycles, "use_light_tree"):
                    scene.cycles.use_light_tree = True
                file_out = passes.compositor_output(scene, layer, denoise_passes=False, passes=kf.GBUFFER_PASSES)
                if per_frame:
                    cost = {}
                    for t in between:
                        cost.update(kf.render_frames(scene, file_out, str(out), [t], 0))
                else:
                    cost = kf.render_frames(scene, file_out, str(out), between, 0)
            runs[name] = {"samples": samples, "persistent_data": persistent, "light_tree": light_tree,
                          "calls": len(between) if per_frame else 1,
                          **summary([cost[t] for t in between])}
    given = sys.argv[1:] if argv is None else argv
    shown = [v for i, v in enumerate(given) if v != "--out" and (i == 0 or given[i - 1] != "--out")]
    doc = {
        "description": f"seconds a G-buffer frame (no Combined, no bounces) costs through the Blender add-on's keyframe export "
                       f"at {w}x{h}, by render setting, beside a keyframe's",
        "format": "x2video-keyframes-gbuffer-cost",
        "command": " ".join(["PYTHONPATH=core:. python bench/results/keyframes/gbuffer_cost.py", *shown]),
        "machine": {**machine_info(), "label": "2-core CPU VM, shared with other jobs (see load_average)"},
        "blender": bpy.app.version_string,
        "room": {"seed": args.seed, "mesh_objects": n_objects, "caption": desc.caption, "build_seconds": build_s},
        "size": [w, h], "threads": args.threads, "gbuffer_frames": len(between),
        "runs": runs,
    }
    doc["headline"] = headline(doc)
    args.out.write_text(json.dumps(clean_json(doc, 4), indent=1) + "\n")
    for name, r in runs.items():
        if name != "export":
            print(f"{name:36s} wall {r['wall_mean']:.3f} s/frame (median {r['wall_median']:.3f}), CPU {r['cpu_mean']:.3f} s/frame")
    print("export:", runs["export"]["frame_seconds"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
