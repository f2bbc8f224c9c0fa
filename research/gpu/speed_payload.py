"""Payload for measuring table (d)'s speed-up on a lent GPU (`research/gpu/speed.py`): what that machine cannot
read or load itself.

The GPU image has no OpenImageIO (the held-out shots are EXR folders) and no diffusers, and the MiniLM text
encoder (92 MB) does not fit a call's 64 MiB. So: the first ROOMS held-out shots, FRAMES frames each, at the
model's size, go as one float16 npz (the channels and the ground-truth rgb, which the reference rows read);
the text embedding of every prompt the measurement uses (only the empty global prompt) goes as a tensor;
the diffusers wheel is copied beside them.

    pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \\
        --platform manylinux2014_x86_64 -d GPU/whl diffusers==0.42.1
    python research/gpu/speed_payload.py --data DATA [--rooms 2] [--frames 17] --wheels GPU/whl --out .gpu/S
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import torch

from x2video.cli.args import size_arg

ROOT = Path(__file__).resolve().parents[2]
CHANNELS = ("albedo", "normal", "roughness", "metallic", "irradiance", "rgb")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--weights", type=Path, default=ROOT / "resources" / "x2video-tiny")
    p.add_argument("--rooms", type=int, default=2)
    p.add_argument("--frames", type=int, default=17)
    p.add_argument("--size", type=size_arg, help="WxH (default: the size the weights were trained at)")
    p.add_argument("--wheels", type=Path, help="folder of wheels to install there (diffusers)")
    p.add_argument("--out", type=Path, required=True)
    a = p.parse_args(argv)
    from x2video.eval.data import load_eval_shots, training_size
    from x2video.model.pipeline import X2VideoModel

    size = a.size or training_size(a.weights) or (160, 112)
    shots = load_eval_shots(a.data, "test", a.rooms, a.frames, size)
    a.out.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for s in shots:
        for c in CHANNELS:
            arrays[f"{s.name}/{c}"] = np.stack([s.shot.channel(c, t) for t in range(s.num_frames)]).astype(np.float16)
    np.savez_compressed(a.out / "shots.npz", **arrays)
    model = X2VideoModel.from_pretrained(a.weights)
    torch.save({"": model.encode_prompts([""]).cpu()}, a.out / "prompts.pt")  # (1, L, D) per prompt
    if a.wheels is not None:
        for w in sorted(a.wheels.glob("*.whl")):
            shutil.copy2(w, a.out / w.name)
    meta = {"rooms": [s.name for s in shots], "frames": a.frames, "size": list(size), "data": str(a.data), "weights": str(a.weights)}
    (a.out / "meta.json").write_text(json.dumps(meta, indent=1))
    total = sum(f.stat().st_size for f in a.out.iterdir())
    print(f"wrote {a.out}: {len(shots)} shots of {a.frames} frames, {total / 2**20:.1f} MiB", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
