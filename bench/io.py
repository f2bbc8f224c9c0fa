"""Benchmark: frames/s for loading a 640x448 shot folder and for exporting it as EXR (folder, multi-layer) and MP4.

    python -m bench.io [--frames 30] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from x2video.channels import INTRINSIC
from x2video.io import load_shot, write_shot_folder
from x2video.io.writers import write_mp4, write_multilayer, write_png_sequence
from x2video.shot import ArrayShot


def synthetic_shot(frames: int, height: int = 448, width: int = 640) -> ArrayShot:
    """A smooth, moving synthetic shot with every intrinsic channel plus rgb and ids (compresses like real renders)."""
    yy, xx = np.mgrid[:height, :width].astype(np.float32)
    arrays: dict[str, list[np.ndarray]] = {k: [] for k in (*INTRINSIC, "rgb", "ids")}
    for t in range(frames):
        u, v = (xx + 3 * t) / width, yy / height
        alb = np.stack([0.5 + 0.4 * np.sin(6 * u), 0.5 + 0.4 * np.cos(5 * v), 0.5 + 0.3 * np.sin(4 * (u + v))], -1)
        n = np.stack([np.sin(3 * u), np.sin(2 * v), np.ones_like(u)], -1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        irr = np.stack([1.5 + np.cos(3 * v)] * 3, -1) * np.float32([1.0, 0.9, 0.8])
        arrays["albedo"].append(alb)
        arrays["normal"].append(n)
        arrays["roughness"].append((0.5 + 0.4 * np.sin(9 * u))[..., None])
        arrays["metallic"].append((u > 0.7).astype(np.float32)[..., None])
        arrays["irradiance"].append(irr)
        arrays["rgb"].append(alb * irr)
        arrays["ids"].append(((u * 8).astype(np.int32) % 8)[..., None])
    return ArrayShot({k: np.stack(v) for k, v in arrays.items()}, fps=10.0)


def timed(fn, n: int) -> float:
    t0 = time.perf_counter()
    fn()
    return n / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args()
    n = args.frames
    shot = synthetic_shot(n)
    res: dict[str, float | str | int] = {"frames": n, "size": "640x448", "machine": platform.machine(), "python": platform.python_version()}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        res["export_exr_folder_fps"] = timed(lambda: write_shot_folder(shot, tmp / "seq"), n)
        res["export_multilayer_exr_fps"] = timed(lambda: write_multilayer(shot, tmp / "ml"), n)
        res["export_png16_fps"] = timed(lambda: write_png_sequence(shot, tmp / "png"), n)
        res["export_mp4_fps"] = timed(lambda: write_mp4(shot, tmp / "a.mp4", channel="rgb"), n)

        def load(path: Path) -> None:
            s = load_shot(path, cache_size=0)
            for t in range(s.num_frames):
                s.frame(t)

        res["load_exr_folder_fps"] = timed(lambda: load(tmp / "seq"), n)
        res["load_multilayer_exr_fps"] = timed(lambda: load(tmp / "ml"), n)
        res["load_png16_fps"] = timed(lambda: load(tmp / "png"), n)
        res["exr_folder_mb_per_frame"] = sum(p.stat().st_size for p in (tmp / "seq").rglob("*.exr")) / n / 1e6
    for k, v in res.items():
        print(f"{k:28s} {v:.2f}" if isinstance(v, float) else f"{k:28s} {v}")
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
