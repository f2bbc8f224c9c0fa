"""Large frames: seconds per frame and peak memory of each tier at 1920x1080, 1366x768 and 1024x1024, and accuracy at 1024x1024.

Speed and memory: every (size, tier) case runs in its own process (`--case`), so one case's memory
cannot inflate another's peak; the case loads the shipped model, renders a shot of `--frames` frames
with `x2video.Renderer` and reports its seconds per frame (render only, the model loaded; the
conditioning encoded inside the render) and its peak resident memory (`getrusage` of that process:
the model, the shot's frames as they are read, the network's working memory). The shot is generated
frame by frame (room-like piecewise-constant channels with windows; speed does not depend on the
content), as a shot folder is read frame by frame. Tiers: 'formula' (albedo x irradiance),
'residual' (the tier-1 net; large frames at a working size of `RenderSettings.residual_pixels`,
`x2video.tiers.residual.residual_frames`), 'residual@full' (the tier-1 net at full size, in tiles beyond
896x896, `x2video.model.residual.apply_tiled`) and 'diffusion' (the fast preset; large frames at a working
resolution, `x2video.conditioning.network`).

Accuracy (`--data`, path-traced shots, e.g. `x2video dataset make --renderer cycles --size 1024x1024`):
each tier beside the formula, scored as `bench/pathtraced.py` scores them (its `evaluate`), tier 1 also at
full size, and the diffusion tier also at the model's training size as working resolution.

    python -m bench.bigframes [--sizes 1920x1080,1366x768,1024x1024] [--tiers formula,residual,diffusion] [--frames 5]
                              [--threads 2] [--data DATA --split test] [--name bigframes]

Results: bench/results/bigframes/NAME.json and NAME.md.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench.common import command, results_path

TIERS = ("formula", "residual", "residual@full", "diffusion")
#: RenderSettings fields of a case's tier beyond its quality (the diffusion tier also takes the fast preset)
TIER_SETTINGS = {"residual@full": {"residual_pixels": 0}}
SIZES = "1920x1080,1366x768,1024x1024"
#: the shipped model's training size: the diffusion tier's other working resolution in the accuracy table
TRAINING_PIXELS = 160 * 112


def room_frame(h: int, w: int, t: int) -> dict[str, np.ndarray]:
    """One frame of room-like channels: piecewise constant in blocks of 1/40 of the width, some windows (normal 0)."""
    import cv2

    rng = np.random.default_rng(1000 + t)
    cell = max(2, w // 40)

    def blocks(c: int, lo: float, hi: float) -> np.ndarray:
        a = rng.uniform(lo, hi, (h // cell + 1, w // cell + 1, c)).astype(np.float32)
        return cv2.resize(a, (w, h), interpolation=cv2.INTER_NEAREST).reshape(h, w, c)

    n = blocks(3, -1, 1)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
    n[blocks(1, 0, 1)[..., 0] > 0.95] = 0
    return {"albedo": blocks(3, 0.05, 0.95), "normal": n, "roughness": blocks(1, 0, 1), "metallic": (blocks(1, 0, 1) > 0.85).astype(np.float32),
            "irradiance": blocks(3, 0, 2)}


def generated_shot(frames: int, h: int, w: int):
    """A `Shot` whose frames are made when read (`room_frame`), so memory holds only the frames in use."""
    from x2video.shot import Shot, ShotInfo

    class GeneratedShot(Shot):
        def __init__(self) -> None:
            self.info = ShotInfo(num_frames=frames, height=h, width=w, channels=("albedo", "normal", "roughness", "metallic", "irradiance"),
                                 source=f"<generated {w}x{h} room>")

        def _read(self, name: str, t: int) -> np.ndarray:
            return room_frame(h, w, t)[name]

    return GeneratedShot()


def cpu_seconds() -> float:
    """User + system CPU seconds of this process: on a shared machine, what the work cost apart from waiting."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # kB on Linux


def run_case(size: tuple[int, int], tier: str, frames: int, threads: int) -> dict:
    """Render one generated shot (in this process) and measure it; see the module docstring."""
    import torch

    torch.set_num_threads(threads)
    from x2video.model.residual import needs_tiles, tile_grid
    from x2video.render.events import FramesReady
    from x2video.render.renderer import Renderer
    from x2video.render.settings import RenderSettings
    from x2video.tiers import registry as tiers
    from x2video.tiers.residual import ResidualTier
    from x2video.weights import load_model

    w, h = size
    t0 = time.perf_counter()
    model = load_model(device="cpu")
    load_s = time.perf_counter() - t0
    rss_loaded = peak_rss_gb()
    shot = generated_shot(frames, h, w)
    ready: list[float] = []
    quality = tier.split("@")[0]
    runs = tiers.get(quality)  # a windowed tier (the sampler's steps) takes the fast preset
    settings = RenderSettings(quality=quality, preset="fast" if not runs.per_frame else None, base="off", **TIER_SETTINGS.get(tier, {}))  # type: ignore[arg-type]

    def on_event(e) -> None:
        if isinstance(e, FramesReady):
            ready.extend([time.perf_counter()] * len(e.frames))

    t0, c0 = time.perf_counter(), cpu_seconds()
    Renderer(model).render(shot, None, settings, on_event)
    secs, cpu = time.perf_counter() - t0, cpu_seconds() - c0
    out = {"size": [w, h], "tier": tier, "frames": frames, "threads": threads, "load_seconds": round(load_s, 2),
           "seconds": round(secs, 2), "sec_per_frame": round(secs / frames, 3), "cpu_seconds_per_frame": round(cpu / frames, 3),
           "first_frame_seconds": round(ready[0] - t0, 2) if ready else None,
           "peak_rss_gb": round(peak_rss_gb(), 3), "rss_after_load_gb": round(rss_loaded, 3)}
    if runs.per_frame and len(ready) > 1:
        out["sec_per_frame_after_first"] = round((ready[-1] - ready[0]) / (len(ready) - 1), 3)
    if runs.needs_model:
        ws = runs.working_size((h, w), settings, model)
        out["working_size"] = None if ws is None else [ws[1], ws[0]]
        f = model.residual_net.cfg.factor if isinstance(runs, ResidualTier) else 0
        if ws is None and f and needs_tiles((h, w), f):  # the tier-1 net at full size, in tiles beyond 896x896
            out["tiles"] = len(tile_grid(h + (-h) % f, w + (-w) % f, factor=f))
    return out


def measure_case(size: tuple[int, int], tier: str, frames: int, threads: int, timeout: float) -> dict:
    """`run_case` in a fresh process (its own peak memory), with the load average around it."""
    cmd = [sys.executable, "-m", "bench.bigframes", "--case", f"{size[0]}x{size[1]}:{tier}", "--frames", str(frames), "--threads", str(threads)]
    before = os.getloadavg()[0]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=os.environ.copy())
    except subprocess.TimeoutExpired:
        return {"size": list(size), "tier": tier, "error": f"timed out after {timeout:.0f} s"}
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode or not lines:
        return {"size": list(size), "tier": tier, "error": (p.stderr or p.stdout).strip().splitlines()[-1:] or [f"exit {p.returncode}"]}
    out = json.loads(lines[-1])
    out["load_average_before_after"] = [round(before, 2), round(os.getloadavg()[0], 2)]
    return out


def accuracy(data: Path, split: str, tiers: list[str], threads: int) -> dict:
    """Each tier beside the formula on the path-traced shots of DATA/split (`bench.pathtraced.evaluate`)."""
    import torch

    from bench.pathtraced import evaluate
    from x2video.render.renderer import Renderer
    from x2video.tiers.registry import windowed
    from x2video.weights import load_model

    torch.set_num_threads(threads)
    renderer = Renderer(load_model(device="cpu"))
    root = data / split if split else data
    shots = sorted(p for p in root.iterdir() if (p / "shot.json").is_file())
    if not shots:
        raise FileNotFoundError(f"{root}: no shot folders (shot.json) to score")
    runs = [(f"{t}|all", t.split("@")[0], "all", TIER_SETTINGS.get(t, {})) for t in tiers]
    # a windowed tier (the diffusion sampler) also with the model's training size as its working resolution
    runs += [(f"{t}@{TRAINING_PIXELS}|all", t, "all", {"working_pixels": TRAINING_PIXELS}) for t in tiers if windowed(t)]
    summary, per_shot = evaluate(renderer, shots, runs)
    return {"shots": [f"{p.parent.name}/{p.name}" for p in shots], "summary": summary, "per_shot": per_shot,
            "ceiling": ceiling(shots, renderer.model.downsample)}


def ceiling(shots: list[Path], factor: int) -> dict:
    """What the working-resolution path can reach with a perfect network: the ground truth area-averaged to the
    working size stands in for the network's frame, brought back to full size by `x2video.conditioning.network.to_full`
    (bilinear or guided) or upsampled alone (bilinear, no formula detail); mean display PSNR over the shots' frames
    per working-pixel budget."""
    import cv2

    from x2video.channels import tonemap
    from x2video.conditioning.frame import plain_conditioning
    from x2video.conditioning.network import UPSAMPLE, resize_area, to_full, working_size
    from x2video.io import load_shot
    from x2video.metrics.image import psnr

    rows: dict[str, dict[str, list[float]]] = {}
    for sp in shots:
        shot = load_shot(sp)
        s = float(shot.info.irradiance_scale)
        for t in range(shot.num_frames):
            gt = shot.channel("rgb", t) * s  # the renderer's units (exposure-normalised)
            cond = plain_conditioning(shot, t)
            disp = tonemap(gt / s)
            for pixels in (TRAINING_PIXELS, 320 * 224):
                ws = working_size(shot.size, factor, pixels)
                if ws is None:
                    continue
                small = resize_area(gt, ws)
                row = rows.setdefault(f"{ws[1]}x{ws[0]}", {})
                row.setdefault("frame upsampled (bilinear)", []).append(
                    psnr(tonemap(cv2.resize(small, shot.size[::-1], interpolation=cv2.INTER_LINEAR) / s), disp))
                for mode in UPSAMPLE:
                    row.setdefault(f"to_full {mode}", []).append(psnr(tonemap(to_full(small, cond, mode) / s), disp))
    return {size: {k: round(float(np.mean(v)), 2) for k, v in row.items()} for size, row in rows.items()}


LABELS = {"albedo_x_irradiance|all": "formula: albedo × irradiance", "formula|all": "tier 0 (formula)",
          "residual|all": "tier 1 (residual net, working ≤ 512×512 px)", "residual@full|all": "tier 1 at full size (tiled)",
          "diffusion|all": "tier 2 (diffusion, fast preset, working 320×224 px budget)",
          f"diffusion@{TRAINING_PIXELS}|all": "tier 2 (fast preset, working at the training size 160×112 px budget)"}


def markdown(result: dict) -> str:
    lines = ["# Large frames (`python -m bench.bigframes`)", "", f"`{result['command']}`", "", f"Machine: {result['machine_note']}"]
    if result["cases"]:
        lines += ["", "| size | tier | s/frame (wall) | CPU s/frame | first frame s | peak RSS GB | RSS after load GB | detail | load avg before/after |",
                  "|---|---|---|---|---|---|---|---|---|"]
    for c in result["cases"]:
        size = f"{c['size'][0]}×{c['size'][1]}"
        if "error" in c:
            lines.append(f"| {size} | {c['tier']} | — | — | — | — | — | {c['error']} | — |")
            continue
        detail = [f"{c['tiles']} tiles"] if c.get("tiles") else []
        if c.get("working_size"):
            detail.append(f"network at {c['working_size'][0]}×{c['working_size'][1]}")
        if c.get("sec_per_frame_after_first") is not None:
            detail.append(f"{c['sec_per_frame_after_first']} s/frame after the first")
        lines.append(f"| {size} | {c['tier']} | {c['sec_per_frame']} | {c['cpu_seconds_per_frame']} | {c['first_frame_seconds']} | {c['peak_rss_gb']} | "
                     f"{c['rss_after_load_gb']} | {'; '.join(detail)} | {c.get('load_average_before_after')} |")
    acc = result.get("accuracy")
    if acc:
        tc = any(v.get("tc") is not None for v in acc["summary"].values())  # shots of two frames or more
        lines += ["", f"Accuracy on {len(acc['shots'])} path-traced shot(s) ({', '.join(acc['shots'])}), display PSNR/SSIM in the shot's units"
                  + (", TC (warping error over the ground truth's)" if tc else "") + ":", "",
                  "| render | PSNR↑ | SSIM↑ | " + ("TC↓ | " if tc else "") + "s/frame |", "|---|---|---|" + ("---|" if tc else "") + "---|"]
        for key, v in acc["summary"].items():
            cell = (f"{v['tc']:.3f} | " if v.get("tc") is not None else "— | ") if tc else ""
            lines.append(f"| {LABELS.get(key, key)} | {v['psnr']:.2f} | {v['ssim']:.4f} | {cell}{v['sec_per_frame']:.2f} |")
        if acc.get("ceiling"):
            lines += ["", "Ceiling of the working-resolution path (the ground truth at working size as a perfect network's frame), PSNR:", "",
                      "| working size | " + " | ".join(next(iter(acc["ceiling"].values()))) + " |", "|---|" + "---|" * len(next(iter(acc["ceiling"].values())))]
            for size, row in acc["ceiling"].items():
                lines.append(f"| {size} | " + " | ".join(f"{v:.2f}" for v in row.values()) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from x2video.cli.args import size_arg

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=SIZES, help="comma-separated WxH ('' for the accuracy table alone)")
    ap.add_argument("--tiers", default=",".join(TIERS), help="comma-separated: formula, residual, diffusion")
    ap.add_argument("--frames", type=int, default=5, help="frames per timed shot (one diffusion window at N = 5)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=3600, help="seconds per case")
    ap.add_argument("--data", type=Path, help="path-traced data set for the accuracy table (e.g. 1024x1024 Cycles shots)")
    ap.add_argument("--split", default="test")
    ap.add_argument("--name", default="bigframes")
    ap.add_argument("--case", help=argparse.SUPPRESS)  # WxH:TIER, run in this process (what the parent spawns)
    args = ap.parse_args(argv)
    if args.case:
        size, tier = args.case.split(":")
        print(json.dumps(run_case(size_arg(size), tier, args.frames, args.threads)), flush=True)
        return 0

    from x2video.eval.machine import machine_info
    from x2video.io.atomic import write_json_atomic, write_text_atomic
    from x2video.io.paths import portable_path

    tiers = [t for t in args.tiers.split(",") if t]
    if bad := set(tiers) - set(TIERS):
        raise SystemExit(f"--tiers: unknown {sorted(bad)} (use {', '.join(TIERS)})")
    cases = []
    for s in [s for s in args.sizes.split(",") if s]:
        for tier in tiers:
            c = measure_case(size_arg(s), tier, args.frames, args.threads, args.timeout)
            print(json.dumps(c), flush=True)
            cases.append(c)
    result = {"format": "x2video-bigframes", "command": command("bigframes", argv), "machine": machine_info("cpu"),
              "machine_note": f"{os.cpu_count()} cores, shared (load average at the start {os.getloadavg()[0]:.1f}); "
                              f"{args.threads} threads per case",
              "goal": "issue 29: 1920x1080 fast preset <= 15 s/frame, peak RSS <= 4 GB; PSNR at 1024x1024 >= the formula's",
              "cases": cases}
    if args.data:
        result["data"] = {"dir": portable_path(args.data), "split": args.split}
        result["accuracy"] = accuracy(args.data, args.split, tiers, args.threads)
        for key, v in result["accuracy"]["summary"].items():
            print(f"{key:32s} PSNR {v['psnr']:6.2f}  SSIM {v['ssim']:.4f}  TC {v.get('tc')}  s/frame {v['sec_per_frame']:.2f}", flush=True)
    dest = results_path("bigframes", args.name)
    dest.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(dest, result)
    write_text_atomic(dest.with_suffix(".md"), markdown(result))
    print(f"wrote {dest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
