"""Issue 31's ratios, side by side in one run: seconds per frame of X2Video's fast and quality presets against
Cycles at 32 samples with OpenImageDenoise, on the same procedural room at 320x224.

1. Cycles renders room SEED (`x2video.cycles.shot.write_room_shot`: 32 samples, denoising on, the passes a
   Blender user hands us) in a child process (bpy stays out of the torch process); its seconds per frame are
   the frames' render times (`render_frames`), without Blender's start-up and the exposure probe.
2. X2Video renders the channels of those very frames (the shot folder, read lazily) with each preset and tier
   in `--runs` (PRESET:QUALITY; a cold render: empty conditioning cache, the engine's graphs built beforehand,
   which happens once per machine), and is scored against Cycles' Combined pass (PSNR on display images, the
   shot's exposure undone, as bench.pathtraced does) beside the formula albedo x irradiance.
Both sides run `--threads` CPU threads (default 1, what the editor uses on a 2-core machine).

    python -m bench.vs_cycles [--frames 9] [--size 320x224] [--seed 7] [--threads 1] [--runs fast:diffusion,quality:diffusion,fast:auto]

Writes bench/results/vs_cycles/vs_cycles.json: {"cycles": {"seconds_per_frame", ...}, "formula_psnr", "runs": [{"preset",
"quality", "tier", "engine", "seconds_per_frame", "speedup_vs_cycles", "psnr", "psnr_minus_formula"}], "machine", ...}.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import command, results_path
from x2video.fields import parse_size

CYCLES_CHILD = """
import json, sys
from x2video.cycles.shot import CyclesConfig, write_room_shot
out, seed, frames, w, h, threads = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6])
secs = []
write_room_shot(out, seed, frames, w, h, cfg=CyclesConfig(samples=32, denoise=True, threads=threads), progress=lambda t, s: secs.append(s))
print("SECONDS " + json.dumps(secs))
"""


def cycles_shot(folder: Path, seed: int, frames: int, width: int, height: int, threads: int) -> list[float]:
    """Render the room with Cycles in a child process; the seconds of each frame."""
    proc = subprocess.run([sys.executable, "-c", CYCLES_CHILD, str(folder), str(seed), str(frames), str(width), str(height), str(threads)],
                          capture_output=True, text=True)
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("SECONDS ")), None)
    if proc.returncode != 0 or line is None:
        raise RuntimeError(f"the Cycles child process failed (exit {proc.returncode}): {proc.stderr[-2000:]}")
    return json.loads(line[len("SECONDS "):])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=9)
    ap.add_argument("--size", default="320x224", help="WxH")
    ap.add_argument("--seed", type=int, default=7, help="procedural room seed")
    ap.add_argument("--threads", type=int, default=1, help="CPU threads of Cycles and of torch/the engine alike")
    ap.add_argument("--runs", default="fast:diffusion,quality:diffusion,fast:auto", help="PRESET:QUALITY entries to time")
    ap.add_argument("--engine", default="auto", help="RenderSettings.engine of the X2Video renders")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    width, height = parse_size(args.size)
    load_before = [round(v, 2) for v in os.getloadavg()]
    with tempfile.TemporaryDirectory(prefix="x2video-vs-cycles-") as tmp:
        folder = Path(tmp) / "room"
        t0 = time.perf_counter()
        secs = cycles_shot(folder, args.seed, args.frames, width, height, args.threads)
        cycles = {"seconds_per_frame": round(float(np.mean(secs)), 4), "frame_seconds": [round(s, 3) for s in secs],
                  "samples": 32, "denoise": "OpenImageDenoise", "wall_seconds_with_startup": round(time.perf_counter() - t0, 2)}
        print(f"Cycles 32 spp + denoise: {cycles['seconds_per_frame']:.3f} s/frame", flush=True)

        import torch

        torch.set_num_threads(args.threads)
        from x2video.channels import tonemap
        from x2video.eval.machine import machine_info
        from x2video.io import load_shot
        from x2video.io.atomic import write_json_atomic
        from x2video.metrics.image import psnr
        from x2video.render.events import FramesReady
        from x2video.render.renderer import Renderer, warm_engine
        from x2video.render.settings import RenderSettings, resolve
        from x2video.tiers import registry as tiers
        from x2video.weights import load_model

        shot = load_shot(folder)
        scale = float(shot.info.irradiance_scale)
        gts = [tonemap(shot.channel("rgb", t)) for t in range(shot.num_frames)]
        formula = float(np.mean([psnr(tonemap(shot.channel("albedo", t) * shot.channel("irradiance", t) / scale), g) for t, g in enumerate(gts)]))
        renderer = Renderer(load_model(device="cpu"))
        runs = []
        for entry in args.runs.split(","):
            preset, quality = entry.split(":")
            s = RenderSettings(preset=preset, quality=quality, engine=args.engine, base="off")
            valid = resolve(s, renderer.model)
            renderer.render(shot, None, RenderSettings(**{**valid.__dict__, "frames": (0, 2), "steps": 1, "preset": None}))  # text encoder, tiers
            if tiers.windowed(renderer.last_tier.tier):  # the sampler's windows: its engine's graphs built outside the clock
                f = renderer.model.downsample
                warm_engine(renderer, renderer.plan(shot, valid), valid, (-(-height // f), -(-width // f)))
            renderer.cache.clear()
            frames: dict[int, np.ndarray] = {}
            t1 = time.perf_counter()
            renderer.render(shot, None, s, on_event=lambda e: frames.update(e.frames) if isinstance(e, FramesReady) else None)
            spf = (time.perf_counter() - t1) / shot.num_frames
            score = float(np.mean([psnr(tonemap(frames[t] / scale), gts[t]) for t in range(shot.num_frames)]))
            tier = renderer.last_tier.tier
            row = {"preset": preset, "quality": quality, "tier": tier, "engine": renderer.engine if tiers.windowed(tier) else None,
                   "seconds_per_frame": round(spf, 4), "speedup_vs_cycles": round(cycles["seconds_per_frame"] / spf, 2),
                   "psnr": round(score, 3), "psnr_minus_formula": round(score - formula, 3)}
            runs.append(row)
            print(f"{preset}:{quality} ({row['tier']}, engine {row['engine']}): {spf:.3f} s/frame, {row['speedup_vs_cycles']:.1f}x Cycles; "
                  f"PSNR {score:.2f} dB vs Cycles (formula {formula:.2f})", flush=True)
    out = args.out or results_path("vs_cycles")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out, {
        "format": "x2video-vs-cycles", "command": command("vs_cycles", argv), "machine": machine_info("cpu"),
        "scene": {"room_seed": args.seed, "frames": args.frames, "size": [width, height]}, "threads": args.threads,
        "cycles": cycles, "formula_psnr": round(formula, 3), "runs": runs,
        "note": "one run, one after the other on the same machine; X2Video renders cold (conditioning encoded inside the render)",
        "load_average_before_after": [load_before, [round(v, 2) for v in os.getloadavg()]],
    })
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
