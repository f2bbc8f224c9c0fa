"""Render speed of the tiny preset (paper Tab. acceleration "Time"): seconds per frame for DDIM-20, DDIM-4 and LCM-2,
Recursive vs Sequential sampling, on this machine's CPU or on a GPU.

Speed does not depend on the weights, so this runs UNTRAINED tiny weights (and, for LCM-2, an
untrained copy of the UNet standing in for the distilled one: the same network, so the same
cost per step) on a synthetic shot with all five channels. It times the conditioning encoding
once per frame (cold), then `Renderer.render` with that cache warm (every UNet call and the VAE
decoding), and reports both per frame. Quality figures live elsewhere.

    python -m bench.render [--frames 17] [--size 320x224] [--device cpu|cuda] [--fp16] [--threads N]

Results are merged into bench/results/render/render.json under a key naming the device, so CPU and
GPU runs sit side by side:
    {"runs": {"<device label>": {"device", "dtype", "torch", "size": [W, H], "frames", "window",
      "weights": "untrained tiny", "encode_seconds_per_frame", "load_average_before_after",
      "results": [{"sampler", "steps", "scheme", "seconds", "seconds_per_frame", "seconds_per_frame_cold",
      "first_frames_seconds", "windows", "unet_calls"}]}}}
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch

from bench.common import results_path
from x2video.io.atomic import write_json_atomic
from x2video.model.pipeline import X2VideoModel
from x2video.sampling.events import FramesReady, RenderSettings, StepDone
from x2video.sampling.renderer import Renderer, plain_conditioning
from x2video.shot import ArrayShot

RESULTS = results_path("render")
CONFIGS = [("ddim", 20), ("ddim", 4), ("lcm", 2)]


def synthetic_shot(frames: int, width: int, height: int, seed: int = 0) -> ArrayShot:
    """Random but valid channels (the content does not change the cost)."""
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(frames, height, width, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return ArrayShot(
        {
            "albedo": rng.uniform(0, 1, (frames, height, width, 3)),
            "normal": n,
            "roughness": rng.uniform(0, 1, (frames, height, width, 1)),
            "metallic": rng.uniform(0, 1, (frames, height, width, 1)),
            "irradiance": rng.uniform(0, 2, (frames, height, width, 3)),
        },
        fps=10.0,
        source="<synthetic bench shot>",
    )


def device_label(device: torch.device) -> str:
    if device.type == "cuda":
        return f"cuda: {torch.cuda.get_device_name(device)}"
    return f"cpu: {platform.processor() or platform.machine()}, {os.cpu_count()} cores (torch threads {torch.get_num_threads()})"


def time_encoding(model: X2VideoModel, shot: ArrayShot, batch: int) -> float:
    """Seconds per frame to encode the conditioning (VAE of 4 channels + shading prior, and for a
    residual model the shading detail the Renderer caches beside it), cold."""
    conds = [plain_conditioning(shot, t) for t in range(shot.num_frames)]
    t0 = time.perf_counter()
    with torch.inference_mode():
        for i in range(0, len(conds), batch):
            cond = model.encode_frames(conds[i : i + batch])
            model.detail(conds[i : i + batch], cond)  # None (free) unless the model is residual
    if model.device.type == "cuda":
        torch.cuda.synchronize()
    return (time.perf_counter() - t0) / len(conds)


def time_render(renderer: Renderer, shot: ArrayShot, settings: RenderSettings) -> dict:
    """One render with the conditioning cache warm (an editor re-render): UNet calls + VAE decoding."""
    first: list[float] = []
    steps = [0]
    t0 = time.perf_counter()

    def on_event(e) -> None:
        if isinstance(e, FramesReady) and not first:
            first.append(time.perf_counter() - t0)
        elif isinstance(e, StepDone):
            steps[0] += 1

    windows = renderer.plan(shot, settings)
    renderer.render(shot, None, settings, on_event=on_event)
    if renderer.model.device.type == "cuda":
        torch.cuda.synchronize()
    seconds = time.perf_counter() - t0
    return {
        "sampler": settings.sampler,
        "steps": settings.steps,
        "scheme": settings.scheme,
        "seconds": round(seconds, 3),
        "seconds_per_frame": round(seconds / shot.num_frames, 4),
        "first_frames_seconds": round(first[0], 3),
        "windows": len(windows),
        "unet_calls": steps[0],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=17, help="shot length L (17 = one keyframe window + 4 interpolation windows at N=5)")
    ap.add_argument("--size", default="320x224", help="WxH")
    ap.add_argument("--window", type=int, default=5)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--fp16", action="store_true")
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    ap.add_argument("--weights", type=Path, default=None, help="model folder (default: the shipped weights in resources/, else untrained tiny)")
    ap.add_argument("--untrained", action="store_true", help="untrained tiny weights even when shipped ones exist")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    device = torch.device(args.device)
    dtype = torch.float16 if args.fp16 else torch.float32

    from x2video.weights import shipped_weights

    weights = None if args.untrained else (args.weights or shipped_weights())
    if weights is None:
        base = X2VideoModel.untrained("tiny", device=device, dtype=dtype)
        lcm = X2VideoModel(base.config, base.unet, base.vae, base.text_encoder, copy.deepcopy(base.unet), device=device, dtype=dtype, untrained=True)
        weights_label = "untrained tiny (speed only); LCM-2 uses an untrained copy of the UNet"
    else:
        lcm = X2VideoModel.from_pretrained(weights, device=device, dtype=dtype)
        if not lcm.has_lcm:
            raise SystemExit(f"{weights} has no lcm_unet.safetensors; LCM-2 cannot be timed (use --untrained for speed only)")
        base = lcm
        cfg = base.config
        weights_label = f"{weights} (vae {list(cfg.vae.block_out_channels)}, f={cfg.vae.downsample}; unet {list(cfg.unet.block_out_channels)})"
    shot = synthetic_shot(args.frames, width, height)
    if args.threads:
        torch.set_num_threads(args.threads)
    ddim = Renderer(base)
    renderers = {"ddim": ddim, "lcm": Renderer(lcm, cache=ddim.cache)}  # same VAE: one conditioning cache
    # warm-up (kernels, allocator, text encoder) and conditioning cache fill
    ddim.render(shot, None, RenderSettings(steps=1, window=args.window))
    encode_s = time_encoding(base, shot, args.window)
    print(f"conditioning encoding: {encode_s:.3f} s/frame (once per frame; cached across renders)")

    load_before = os.getloadavg()
    results = []
    for scheme in ("recursive", "sequential"):
        for sampler, steps in CONFIGS:
            s = RenderSettings(sampler=sampler, steps=steps, window=args.window, scheme=scheme)
            res = time_render(renderers[sampler], shot, s)
            results.append(res)
            res["seconds_per_frame_cold"] = round(res["seconds_per_frame"] + encode_s, 4)
            print(f"{scheme:10s} {sampler}-{steps:<3d} {res['seconds_per_frame']:.3f} s/frame warm, {res['seconds_per_frame_cold']:.3f} cold  "
                  f"({res['seconds']:.1f} s, {res['windows']} windows, first frames after {res['first_frames_seconds']:.2f} s)")

    label = device_label(device) + ("" if weights is None else " shipped")
    data = json.loads(args.out.read_text()) if args.out.is_file() else {"runs": {}}
    data.setdefault("runs", {})[label] = {
        "device": label,
        "dtype": str(dtype).replace("torch.", ""),
        "torch": torch.__version__,
        "size": [width, height],
        "frames": args.frames,
        "window": args.window,
        "weights": weights_label,
        "encode_seconds_per_frame": round(encode_s, 4),
        "note": "seconds_per_frame: UNet calls + VAE decoding with the conditioning cache warm (editor re-render); "
        "seconds_per_frame_cold adds encode_seconds_per_frame (first render of a shot)",
        "load_average_before_after": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
        "results": results,
    }
    write_json_atomic(args.out, data)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
