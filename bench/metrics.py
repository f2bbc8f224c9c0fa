"""Benchmark: seconds per frame of each metric (PSNR, SSIM, FID features, FID distance, TC exact / DIS) on CPU.

Synthetic frames (a smooth moving pattern plus noise) at the shot format's 320x224 by default;
the numbers do not depend on content except DIS, which barely does.

    python -m bench.metrics [--frames 9] [--width 320 --height 224] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

from x2video.metrics.fid import fid_from_features, frechet_distance, gaussian_stats, inception_features, load_inception
from x2video.metrics.image import psnr, ssim
from x2video.metrics.temporal import temporal_consistency


def make_video(n: int, h: int, w: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    out = []
    for t in range(n):
        base = 0.5 + 0.3 * np.stack([np.sin(0.05 * (x - 1.5 * t) + c + 0.03 * y) for c in range(3)], -1)
        out.append(np.clip(base + rng.normal(0, 0.02, base.shape), 0, 1).astype(np.float32))
    return out


CPU: dict[str, float] = {}


def timed(fn, key: str = "") -> float:
    """Wall-clock seconds of fn(); its process CPU seconds (all threads) go to CPU[key]."""
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    if key:
        CPU[key] = time.process_time() - c0
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=9)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=224)
    ap.add_argument("--fid-dim-check", action="store_true", help="also time the 2048x2048 eigenvalue Fréchet route")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    n, h, w = args.frames, args.height, args.width
    gt, pred = make_video(n, h, w, 0), make_video(n, h, w, 1)
    motion = np.zeros((n - 1, h, w, 2), np.float32)
    motion[..., 0] = 1.5

    res: dict[str, float] = {}
    res["psnr_s_per_frame"] = timed(lambda: [psnr(p, g) for p, g in zip(pred, gt)], "psnr") / n
    res["ssim_s_per_frame"] = timed(lambda: [ssim(p, g) for p, g in zip(pred, gt)], "ssim") / n
    res["tc_exact_s_per_frame"] = timed(lambda: temporal_consistency(pred, gt, motion), "tc_exact") / n
    res["tc_dis_s_per_frame"] = timed(lambda: temporal_consistency(pred, gt), "tc_dis") / n
    load_inception()
    inception_features(np.stack(gt[:2]))  # warm-up (TorchScript profiling runs)
    feats = {}
    res["fid_features_s_per_frame"] = timed(
        lambda: feats.update(a=inception_features(np.stack(gt)), b=inception_features(np.stack(pred))), "fid_features_2n"
    ) / (2 * n)
    res["fid_distance_lowrank_s"] = timed(lambda: fid_from_features(feats["a"], feats["b"]))
    if args.fid_dim_check:
        rng = np.random.default_rng(0)
        fa, fb = rng.normal(size=(2100, 2048)), rng.normal(size=(2100, 2048))
        stats = (*gaussian_stats(fa), *gaussian_stats(fb))
        res["fid_distance_eig_2048_s"] = timed(lambda: frechet_distance(*stats))
    out = {
        "frames": n,
        "size": [h, w],
        "machine": f"{platform.machine()} {os.cpu_count()} cores, torch threads {torch.get_num_threads()}",
        "load_average": os.getloadavg() if hasattr(os, "getloadavg") else None,
        **res,
        "cpu_s_per_frame": {k: v / (2 * n if k.endswith("_2n") else n) for k, v in CPU.items()},
    }
    text = json.dumps(out, indent=2)
    if args.json:
        args.json.write_text(text)
    sys.stdout.write(text + "\n")


if __name__ == "__main__":
    main()
