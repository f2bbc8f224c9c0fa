"""How far tier 1 corrects the formula on validation data: the reason for `x2video.model.plausible`'s bounds (issue 49).

For every frame of the given validation shots, at their own size and resampled to larger ones (tier 1 runs at a
working size there, `RenderSettings.residual_pixels`), tier 1's frame as the product renders it without the guard
(`residual_frames`, the unseen-light rule on) and the truth are compared with the formula by
`plausible.log_ratios` (per tile of the guard's grid, and over the frame). Tier 1's own distribution sets the
bounds: a correction larger than any the net made on such data is one it was never seen to need. The truth's
is reported beside it, to say why it cannot set them: the truth holds what no channel says (a window's view, a
lamp's glow), so it is far from the formula where tier 1 correctly keeps it (the unseen-light rule). With
`--fool`, the same frames with the irradiance scaled by factors no renderer's exposure normalisation leaves
(in memory, no 8-bit clipping) show where the bounds engage.

    python -m bench.plausible_bound --data VALIDATION_SHOT [...] [--procedural 8,18,28,38,48] [--sizes 1024x1024,1920x1080] [--fool 0.01,100]

`--procedural` adds the procedural (rasterized) renderer's validation rooms of data set seed 43 (4 frames at 320x224,
rendered into a temporary folder): rooms whose index is 8 modulo 10 (`x2video.procedural.dataset.room_split`).

Writes bench/results/plausible_bound/plausible_bound.json.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

PERCENTILES = (50, 90, 99, 99.9, 100)


def _dist(v: list[float]) -> dict:
    a = np.abs(np.asarray(v, np.float64))
    return {"n": int(a.size), **{f"p{p:g}": round(float(np.percentile(a, p)), 4) for p in PERCENTILES}} if a.size else {"n": 0}


def measure(shot, net, frames: list[int], max_pixels: int, gain: float = 1.0) -> dict:
    """Per-tile and per-frame |log ratio| lists of tier 1 and of the truth to the formula over `frames` of `shot`
    (irradiance x `gain`)."""
    from x2video.conditioning.frame import plain_conditioning
    from x2video.formula import formula
    from x2video.model import plausible
    from x2video.tiers.residual import residual_frames

    out: dict[str, list[float]] = {"tier1_tiles": [], "tier1_frames": [], "truth_tiles": [], "truth_frames": []}
    s = float(shot.info.irradiance_scale)
    for t in frames:
        c = plain_conditioning(shot, t)
        if gain != 1.0:
            c.channels["irradiance"] = c.channels["irradiance"] * gain
        f = formula(c.channels)
        r = residual_frames(net, [c], max_pixels=max_pixels)[0]
        for key, x in (("tier1", r), ("truth", shot.channel("rgb", t) * s * gain if shot.has("rgb") else None)):
            if x is None:
                continue
            whole, tiles = plausible.log_ratios(x, f)
            out[f"{key}_frames"].append(whole)
            out[f"{key}_tiles"].extend(tiles.ravel().tolist())
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, nargs="+", default=None, help="validation shots (never test rooms) with rgb truth")
    ap.add_argument("--sizes", default="1024x1024,1920x1080", help="sizes (WxH) to resample them to besides their own")
    ap.add_argument("--frames", type=int, default=0, help="frames per shot (0: all)")
    ap.add_argument("--procedural", default="", help="indices of procedural validation rooms (seed 43) to render and add")
    ap.add_argument("--fool", default="0.01,100", help="irradiance gains that fool tier 1 (in memory), to show the bounds engage")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    import torch

    from bench.common import clean_json, command, results_path
    from bench.stability_shots import ViewShot
    from x2video.io import load_shot
    from x2video.io.atomic import write_json_atomic
    from x2video.io.paths import portable_path
    from x2video.model import plausible
    from x2video.render.settings import RenderSettings
    from x2video.weights import load_model

    torch.set_num_threads(args.threads)
    net = load_model(None, device="cpu").residual_net
    max_pixels = RenderSettings().residual_pixels
    sizes = [None] + [tuple(int(v) for v in s.split("x"))[::-1] for s in args.sizes.split(",") if s]
    t0 = time.perf_counter()
    pooled: dict[str, list[float]] = {}
    by_size: dict[str, dict] = {}
    fooled: dict[str, dict] = {}
    data = list(args.data or [])
    if args.procedural:
        import tempfile

        from x2video.procedural.dataset import room_seed, room_split
        from x2video.procedural.shotgen import write_procedural_shot

        tmp = Path(tempfile.mkdtemp(prefix="x2video-procedural-val-"))
        for i in (int(v) for v in args.procedural.split(",")):
            if room_split(i, 10, True) != "val":
                raise SystemExit(f"--procedural: room {i} is a {room_split(i, 10, True)} room, not a validation room")
            data.append(write_procedural_shot(tmp / f"procedural_s43_room{i:05d}", room_seed(43, i), 4, 320, 224))
    for d in data:
        src = load_shot(d)
        frames = list(range(src.num_frames if not args.frames else min(args.frames, src.num_frames)))
        for size in sizes:
            shot = src if size is None else ViewShot(src, size=size)
            m = measure(shot, net, frames, max_pixels)
            key = f"{d.parent.name}/{d.name} at {shot.size[1]}x{shot.size[0]}"
            by_size[key] = {k: _dist(v) for k, v in m.items()}
            for k, v in m.items():
                pooled.setdefault(k, []).extend(v)
            print(key, {k: by_size[key][k].get("p100") for k in m}, flush=True)
        for g in (float(v) for v in args.fool.split(",") if v):
            m = measure(src, net, frames[:4], max_pixels, gain=g)
            fooled[f"{d.parent.name}/{d.name}, irradiance x{g:g}"] = {k: _dist(v) for k, v in m.items() if k.startswith("tier1")}
            print("fool", d.name, g, {k: round(max(map(abs, v)), 3) for k, v in m.items() if v}, flush=True)
    out = {"format": "x2video-plausible-bound", "command": command("plausible_bound", argv),
           "description": "how far tier 1 corrects the formula on validation data (|log ratio| of mean luminance per tile and per frame), "
                          "the reason for x2video.model.plausible's TILE_BOUND and FRAME_BOUND",
           "data": [portable_path(d) for d in args.data or []], "procedural_validation_rooms": args.procedural,
           "grid": plausible.GRID, "floor": plausible.FLOOR,
           "tile_bound": plausible.TILE_BOUND, "frame_bound": plausible.FRAME_BOUND,
           "validation": {k: _dist(v) for k, v in pooled.items()}, "by_size": by_size, "fooled": fooled,
           "seconds": round(time.perf_counter() - t0, 1)}
    dest = results_path("plausible_bound")
    dest.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(dest, clean_json(out, 4))
    print(f"wrote {portable_path(dest)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
