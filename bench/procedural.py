"""Benchmark and contact sheet of the procedural interior renderer (issue 3).

    python -m bench.procedural speed [--sizes 320x224 640x448] [--rooms 3] [--frames 20]
    python -m bench.procedural sheet [--out docs/procedural_contact_sheet.png] [--rooms 8]
    python -m bench.procedural flow [--rooms 10] [--frames 60] [--size 640x448]

`speed` times the whole per-frame pipeline (render all channels + exact motion + EXR writing) and reports frames/s
and the CPU time per frame (the wall clock is shared with other jobs on the dev machine). `flow` reports the mean
optical flow between consecutive frames (the paper's data set: 3.16 px at 640x448).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from x2video.channels import tonemap
from x2video.fields import parse_size
from x2video.procedural.camera import camera_path
from x2video.procedural.renderer import ProceduralRenderer
from x2video.procedural.scene import generate_scene
from x2video.procedural.shotgen import render_frames, write_procedural_shot


def speed(args: argparse.Namespace) -> dict:
    results = {}
    for size in args.sizes:
        w, h = parse_size(size)
        r = ProceduralRenderer(w, h)
        with tempfile.TemporaryDirectory() as tmp:
            wall0, cpu0, n = time.perf_counter(), time.process_time(), 0
            for i in range(args.rooms):
                write_procedural_shot(Path(tmp) / f"r{i}", 1000 + i, args.frames, w, h, renderer=r)
                n += args.frames
            wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        r.release()
        # render only (no EXR writing, no motion): what a GPU would speed up
        r = ProceduralRenderer(w, h)
        sc = generate_scene(1000)
        poses = camera_path(sc, args.frames, w / h, 1000)
        r.set_scene(sc, poses)
        t0, c0 = time.perf_counter(), time.process_time()
        for p in poses:
            r.render(p)
        rw, rc = time.perf_counter() - t0, time.process_time() - c0
        r.release()
        results[size] = {"frames": n, "fps_all": n / wall, "cpu_s_per_frame_all": cpu / n,
                         "fps_render_only": len(poses) / rw, "cpu_s_per_frame_render_only": rc / len(poses),
                         "hours_for_200x60": 200 * 60 / (n / wall) / 3600}
        print(f"{size}: {n / wall:.2f} frames/s all channels+motion+EXR (CPU {cpu / n * 1000:.0f} ms/frame); "
              f"render only {len(poses) / rw:.2f} frames/s (CPU {rc / len(poses) * 1000:.0f} ms/frame); "
              f"200 rooms x 60 frames: {results[size]['hours_for_200x60']:.2f} h", flush=True)
    return results


def flow(args: argparse.Namespace) -> dict:
    w, h = parse_size(args.size)
    r = ProceduralRenderer(w, h)
    means = []
    for i in range(args.rooms):
        sc = generate_scene(2000 + i)
        poses = camera_path(sc, args.frames, w / h, 2000 + i)
        mags = []
        for t, ch in render_frames(sc, poses, r):
            if "motion" in ch:
                m = np.linalg.norm(ch["motion"], axis=-1)
                mags.append(float(np.nanmean(m)))
        means.append(float(np.mean(mags)))
        print(f"room {2000 + i}: mean flow {means[-1]:.2f} px", flush=True)
    r.release()
    print(f"mean optical flow between consecutive frames at {args.size}: {np.mean(means):.2f} px over {args.rooms} rooms")
    return {"size": args.size, "mean_flow_px": float(np.mean(means)), "per_room": means}


def _u8(x: np.ndarray) -> np.ndarray:
    return (np.clip(x, 0, 1) * 255 + 0.5).astype(np.uint8)


def sheet(args: argparse.Namespace) -> dict:
    import cv2

    w, h = 256, 176
    r = ProceduralRenderer(w, h)
    rows = []
    for i in range(args.rooms):
        seed = args.seed + i
        sc = generate_scene(seed)
        poses = camera_path(sc, 40, w / h, seed)
        r.set_scene(sc, poses)
        f = r.render(poses[20])
        irr = f["irradiance"]
        tiles = [_u8(tonemap(f["rgb"])), _u8(tonemap(f["albedo"])), _u8(f["normal"] * 0.5 + 0.5),
                 _u8(np.repeat(f["roughness"], 3, -1)), _u8(np.repeat(f["metallic"], 3, -1)), _u8(tonemap(irr))]
        row = np.concatenate([np.pad(t, ((2, 2), (2, 2), (0, 0)), constant_values=255) for t in tiles], 1)
        band = np.full((18, row.shape[1], 3), 255, np.uint8)
        label = f"room seed {seed}: {sc.caption} ({sc.width:.1f} x {sc.depth:.1f} x {sc.height:.1f} m, {len(sc.objects)} objects)"
        cv2.putText(band, label, (6, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
        rows.append(np.concatenate([band, row], 0))
    r.release()
    head = np.full((22, rows[0].shape[1], 3), 255, np.uint8)
    for k, name in enumerate(["rgb (tonemap)", "albedo", "normal (camera)", "roughness", "metallic", "irradiance (tonemap)"]):
        cv2.putText(head, name, (k * (w + 4) + 6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    img = np.concatenate([head] + rows, 0)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB)")
    return {"out": str(out)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("speed")
    s.add_argument("--sizes", nargs="+", default=["320x224", "640x448"])
    s.add_argument("--rooms", type=int, default=3)
    s.add_argument("--frames", type=int, default=20)
    s.add_argument("--json", help="also write the figures to this JSON file")
    f = sub.add_parser("flow")
    f.add_argument("--rooms", type=int, default=10)
    f.add_argument("--frames", type=int, default=60)
    f.add_argument("--size", default="640x448")
    f.add_argument("--json")
    c = sub.add_parser("sheet")
    c.add_argument("--out", default="docs/procedural_contact_sheet.png")
    c.add_argument("--rooms", type=int, default=8)
    c.add_argument("--seed", type=int, default=100)
    c.add_argument("--json")
    args = p.parse_args(argv)
    res = {"speed": speed, "flow": flow, "sheet": sheet}[args.cmd](args)
    if getattr(args, "json", None):
        Path(args.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
