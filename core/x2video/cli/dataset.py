"""`x2video dataset make|outside|truth|demo`: generate procedural interior shots (train/test split by room, resumable), the
outside scenes, and a truth apart from the passes for test shots."""
from __future__ import annotations

import argparse
import time

from x2video.fields import parse_size
from x2video.procedural.demo import DEMO


def make(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    if args.renderer == "cycles":  # Blender's path tracer, in processes of its own
        from x2video.cycles.dataset import make_cycles

        return make_cycles(args, *parse_size(args.size, 8))

    from x2video.procedural.dataset import make_dataset

    if not args.out:
        raise SystemExit("x2video dataset make --renderer raster: --out is required (only Cycles sets have a default cache folder)")
    bar = tqdm(unit="room", desc="rooms")
    t0, first = time.perf_counter(), None

    def on_room(done: int, total: int) -> None:
        nonlocal first
        if first is None:
            first = done
            bar.reset(total=total)
        bar.n = done
        frames = (done - first) * args.frames
        bar.set_postfix(fps=f"{frames / (time.perf_counter() - t0):.2f}", refresh=True)

    try:
        doc = make_dataset(args.out, args.rooms, args.frames, parse_size(args.size, 8), seed=args.seed, test_every=args.test_every,
                           workers=args.workers, on_room=on_room)
    finally:
        bar.close()
    splits = doc["splits"]
    print(f"{args.rooms} rooms in {args.out} ({len(splits['train'])} train, {len(splits['test'])} test)")
    return 0


def demo(args: argparse.Namespace) -> int:
    from x2video.procedural.demo import write_demo

    out = write_demo(args.out)
    print(f"demo shot ({DEMO['frames']} frames, {DEMO['width']}x{DEMO['height']}) in {out}")
    return 0


def _outside(args: argparse.Namespace) -> int:
    from x2video.cycles.outside.dataset import make_outside

    return make_outside(args)


def _truth(args: argparse.Namespace) -> int:
    from x2video.cycles.truth import make_truth

    return make_truth(args)


def register(subparsers) -> None:
    p = subparsers.add_parser("dataset", help="generate procedural interior shots (training data, demo scene)")
    sub = p.add_subparsers(dest="dataset_command", metavar="ACTION")
    sub.required = True
    m = sub.add_parser("make", help="render N procedural rooms into DIR/train/room_XXXXX and DIR/test/room_XXXXX (resumable)")
    m.add_argument("--rooms", type=int, required=True, help="number of rooms (one shot each)")
    m.add_argument("--frames", type=int, default=60, help="frames per shot")
    m.add_argument("--size", default="320x224", help="WIDTHxHEIGHT in pixels")
    m.add_argument("--seed", type=int, default=0, help="data set seed; room i uses scene seed seed*1000003+i")
    m.add_argument("--out", default=None, help="output folder (cycles: default a cache folder keyed by generator version, seed, size"
                                                 " and samples, under $X2VIDEO_DATA_CACHE or ~/.cache/x2video/datasets)")
    m.add_argument("--workers", type=int, default=1, help="parallel processes (one EGL context each)")
    m.add_argument("--test-every", type=int, default=10, help="every N-th room goes to the test split (0: no test split)")
    m.add_argument("--renderer", choices=("raster", "cycles"), default="raster",
                   help="raster: the fast moderngl renderer (shot folders); cycles: Blender's path tracer through bpy (Blender"
                        " multi-layer EXR shots with a val split; needs `pip install 'x2video-studio[cycles]'`)")
    m.add_argument("--samples", type=int, default=32, help="cycles: path-tracing samples per pixel (Combined and the light passes are denoised)")
    m.add_argument("--clips", type=int, default=1, help="cycles: clips of --frames frames per training room, each along its own camera"
                                                         " path (the room is built once; test and validation rooms get one)")
    m.add_argument("--eval-frames", type=int, default=0, help="cycles: frames per validation and test room (0: --frames)")
    m.add_argument("--minutes", type=float, default=0.0, help="cycles: build budget in minutes (0: none); no room starts after it,"
                                                               " the same command resumes")
    m.add_argument("--generator", type=int, default=0, help="cycles: room generator version (0: the newest, 3: textures, decor,"
                                                            " backdrops; 2: the rooms of earlier sets)")
    m.add_argument("--splits", default=None, help="cycles: render only these splits, e.g. 'test' (comma-separated; default all)")
    m.set_defaults(func=make)
    o = sub.add_parser("outside", help="path-trace the hand-written outside test scenes into DIR/test/<scene> (Cycles, resumable)")
    o.add_argument("--out", required=True, help="output folder")
    o.add_argument("--size", default="320x224", help="WIDTHxHEIGHT in pixels")
    o.add_argument("--frames", type=int, default=12, help="frames per scene")
    o.add_argument("--samples", type=int, default=32, help="path-tracing samples per pixel (Combined is denoised)")
    o.add_argument("--scenes", default="kitchen,corridor,night_mirror", help="comma-separated scenes to render")
    o.add_argument("--threads", type=int, default=0, help="render threads of the Blender process (0: every core; the scenes"
                                                          " render one at a time)")
    o.set_defaults(func=_outside)
    t = sub.add_parser("truth", help="render a truth apart from the passes (more samples, another seed) into DIR/<split>/<shot>/truth/"
                                     " for finished Cycles rooms and outside scenes (resumable)")
    t.add_argument("--data", required=True, help="data set folder (DATA/<split>/<shot>/shot.json)")
    t.add_argument("--split", default="test", help="split(s) to give a truth apart, comma-separated (e.g. 'val,test')")
    t.add_argument("--samples", type=int, default=0, help="samples per pixel of the truth (+ OpenImageDenoise; 0: twice the shot's,"
                                                          " at least 32)")
    t.add_argument("--seed", type=int, default=1, help="Cycles noise seed of the truth (the passes use 0)")
    t.add_argument("--threads", type=int, default=0, help="render threads of the Blender process (0: every core)")
    t.set_defaults(func=_truth)
    d = sub.add_parser("demo", help="write the small demo shot (1 room, 33 frames, 320x224, deterministic)")
    d.add_argument("out", help="output shot folder")
    d.set_defaults(func=demo)
