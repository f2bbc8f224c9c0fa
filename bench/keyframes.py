"""Path-traced keyframes (issue 51): fill the frames between 1 keyframe in N, and score every method beside Cycles.

On the clips of `bench.clips` (one Cycles render of a room's passes, whose Combined is used on the keyframes only,
and a truth rendered apart at more samples with another seed), for N in `--every`:

- methods on the frames between: hold (the nearest keyframe), RIFE (colour only: `bench.rife`), the classical
  fill by reprojection (`x2video.base.fill`, by depth and camera), the same by G-buffer flow (as on a shot without
  depth or camera), the learned fill (`x2video.base.learned`: the classical fill corrected by the fill network, from
  `--fill` or beside the shipped weights; skipped, saying why, where there are none), the diffusion tier with every
  keyframe as a reference (`RenderSettings.fill` 'diffusion', the paper's Ref-Keyframe: the shipped weights, or
  `--weights`, at `--preset`; the whole clip rendered once per N, its time shared by the frames between), each scored
  by PSNR and SSIM on the frames between and TC over the whole clip (keyframes included), against the truth;
- cost per frame = keyframe cost / N + G-buffer frame cost + the method's own seconds, beside Cycles at the
  keyframes' samples and at 1, 2, 4 samples + OIDN on every frame (their PSNR against the same truth).

    python -m bench.keyframes [--clips DIR] [--size 320x224] [--seeds S] [--every 2,4,8,16] [--validation] [--fill DIR]
                              [--methods hold,diffusion]

`--validation` scores the validation clip only (where the fill's settings are chosen); without it, the test clips
(`bench.clips.TEST_SEEDS`, or those of them in `--seeds`) are scored and written to
bench/results/keyframes/keyframes.json (keyframes_960x540.json at --size 960x540, beside the G-buffer cost of that
size, gbuffer_cost_960x540.json).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from bench.clips import TEST_SEEDS, VALIDATION_SEEDS, default_root
from bench.common import clean_json, command, results_path
from x2video.channels import tonemap
from x2video.eval.machine import machine_info
from x2video.fields import parse_size
from x2video.metrics.image import psnr, ssim
from x2video.metrics.temporal import temporal_consistency

GBUFFER_COST = Path(__file__).parent / "results" / "keyframes" / "gbuffer_cost.json"
#: the size the default result files are at; other sizes' carry it in their names (keyframes_960x540.json,
#: gbuffer_cost_960x540.json)
DEFAULT_SIZE = "320x224"


def gbuffer_cost_path(size: str) -> Path:
    """The G-buffer cost file of `size` (`bench/results/keyframes/gbuffer_cost.py --size S --out` that path)."""
    return GBUFFER_COST if size == DEFAULT_SIZE else GBUFFER_COST.with_name(f"gbuffer_cost_{size}.json")


def result_name(validation: bool, size: str) -> str:
    """The result file's stem: keyframes[_validation][_WxH] (no size for the default one)."""
    return ("keyframes_validation" if validation else "keyframes") + ("" if size == DEFAULT_SIZE else f"_{size}")


def read_exr_rgb(path: Path) -> np.ndarray:
    from x2video.io.image import read_image

    return read_image(path).stack(["R", "G", "B"]).astype(np.float32)


def load_clip(folder: Path) -> tuple[Any, list[np.ndarray], dict]:
    """(the passes shot, the truth's linear frames, clip.json) of one clip."""
    from x2video.io.load import load_shot

    meta = json.loads((folder / "clip.json").read_text())
    shot = load_shot(folder / "passes")
    truth = [read_exr_rgb(folder / "truth" / f"{t:06d}.exr") for t in range(shot.num_frames)]
    return shot, truth, meta


def hold(shot: Any, keys: list[int], t: int) -> np.ndarray:
    """The nearest keyframe's rgb (the earlier one on a tie)."""
    return shot.channel("rgb", min(keys, key=lambda k: (abs(k - t), k)))


def rife(shot: Any, keys: list[int], t: int) -> np.ndarray:
    """RIFE between the two keyframes around t, on display images; returned as linear (sRGB decoded)."""
    from bench.rife import interpolate
    from x2video.base.fill import nearest_keyframes
    from x2video.channels import srgb_to_linear

    near = nearest_keyframes(t, keys)
    if len(near) == 1:
        return shot.channel("rgb", near[0])
    a, b = near
    return srgb_to_linear(interpolate(tonemap(shot.channel("rgb", a)), tonemap(shot.channel("rgb", b)), (t - a) / (b - a)))


def classical(shot: Any, keys: list[int], t: int, cache: dict) -> np.ndarray:
    from x2video.base.fill import fill_frame

    return fill_frame(shot, t, keyframes=keys, shading=cache).rgb


def diffusion(shot: Any, keys: list[int], t: int, cache: dict, model: Any, preset: str) -> np.ndarray:
    """Tier 2 with the keyframes as references (fill 'diffusion'): the whole clip rendered on the first call (its frames
    kept in `cache`, in the rgb's units), frame t after."""
    if "diffusion" not in cache:
        from x2video.io.units import OutputUnits
        from x2video.render.events import FramesReady
        from x2video.render.renderer import Renderer
        from x2video.render.settings import RenderSettings

        frames: dict[int, np.ndarray] = {}

        def on_event(e: Any) -> None:
            if isinstance(e, FramesReady):
                frames.update(e.frames)

        settings = RenderSettings(fill="diffusion", keyframes=",".join(map(str, keys)), preset=preset)  # type: ignore[arg-type]
        Renderer(model, retain=False).render(shot, None, settings, on_event)
        units = OutputUnits.for_shot(shot)
        cache["diffusion"] = {f: units.scene(v) for f, v in frames.items()}
    return cache["diffusion"][t]


class NoDepth:
    """The shot as one without depth and camera (the fill falls back to G-buffer flow)."""

    def __init__(self, shot: Any):
        self._shot = shot
        from dataclasses import replace

        self.info = replace(shot.info, poses=None, channels=tuple(c for c in shot.channels if c != "depth"))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._shot, name)

    def has(self, name: str, t: int | None = None) -> bool:
        return name != "depth" and self._shot.has(name, t)

    @property
    def keyframes(self) -> tuple[int, ...]:
        return self._shot.keyframes

    @property
    def size(self) -> tuple[int, int]:
        return self._shot.size


def methods(fill: Any = None, model: Any = None, preset: str = "fast") -> dict[str, Callable[..., np.ndarray]]:
    """The methods by name; "learned" only with `fill` (a `LearnedFill`), "diffusion" only with `model` (a `RenderModel`)."""
    out = {
        "hold": lambda shot, keys, t, cache: hold(shot, keys, t),
        "rife": lambda shot, keys, t, cache: rife(shot, keys, t),
        "classical": classical,
        "classical_flow": lambda shot, keys, t, cache: classical(NoDepth(shot), keys, t, cache),
    }
    if fill is not None:
        from x2video.base.fill import fill_frame

        out["learned"] = lambda shot, keys, t, cache: fill_frame(shot, t, keyframes=keys, shading=cache, learned=fill).rgb
    if model is not None:
        out["diffusion"] = lambda shot, keys, t, cache: diffusion(shot, keys, t, cache, model, preset)
    return out


def fill_sha(fill: Any) -> str:
    """sha256 (first 16 hex digits) of the fill network's weights file: which weights a result was measured with."""
    import hashlib

    return hashlib.sha256((fill.folder / "fill.safetensors").read_bytes()).hexdigest()[:16]


def learned_fill(folder: str | None) -> Any:
    """The learned fill from `folder` (else beside the shipped weights), or None, printing why, where there is none."""
    from x2video.base.learned import load_learned_fill

    try:
        return load_learned_fill(folder)
    except FileNotFoundError as e:
        print(f"learned: skipped ({e})", flush=True)
        return None


def score_clip(folder: Path, every: list[int], names: list[str], fill: Any = None, model: Any = None, preset: str = "fast") -> dict:
    shot, truth, meta = load_clip(folder)
    n = shot.num_frames
    gts = [tonemap(f) for f in truth]
    key_cost = float(np.mean(meta["passes"]["seconds"])) if "passes" in meta else None
    rows = []
    for N in every:
        keys = list(range(0, n, N))
        if keys[-1] != n - 1:
            keys.append(n - 1)
        between = [t for t in range(n) if t not in keys]
        for name in names:
            fn, cache, secs = methods(fill, model, preset)[name], {}, []
            if between:  # loading a method (RIFE's weights, graphs) is off the clock, as a render's model load is
                fn(shot, keys, between[0], {})
            disp = {}
            for t in range(n):
                if t in keys:
                    disp[t] = tonemap(shot.channel("rgb", t))
                    continue
                t0 = time.perf_counter()
                disp[t] = tonemap(fn(shot, keys, t, cache))
                secs.append(time.perf_counter() - t0)
            video = [disp[t] for t in range(n)]
            p = [psnr(disp[t], gts[t]) for t in between]
            rows.append({"clip": folder.name, "every": N, "method": name, "psnr": float(np.mean(p)), "psnr_min": float(np.min(p)),
                         "psnr_frames": {str(t): float(v) for t, v in zip(between, p)},
                         "ssim": float(np.mean([ssim(disp[t], gts[t]) for t in between])),
                         "tc": float(temporal_consistency(video, gts).tc),
                         "fill_seconds": float(np.mean(secs)) if secs else 0.0, "keyframe_seconds": key_cost})
            print(f"{folder.name} N={N:2d} {name:15s} {rows[-1]['psnr']:6.2f} dB (min {rows[-1]['psnr_min']:.2f}) "
                  f"SSIM {rows[-1]['ssim']:.4f} TC {rows[-1]['tc']:.3f} {rows[-1]['fill_seconds']:.3f} s", flush=True)
    cycles = []
    for name, rec in meta.items():
        if isinstance(rec, dict) and name.startswith("cycles-"):
            frames = [read_exr_rgb(folder / name / f"{t:06d}.exr") for t in range(n)]
            cycles.append({"clip": folder.name, "samples": rec["samples"], "seconds_per_frame": float(np.mean(list(rec["seconds"].values()))),
                           "cpu_seconds_per_frame": float(np.mean(list(rec["cpu_seconds"].values()))),
                           "psnr": float(np.mean([psnr(tonemap(f), g) for f, g in zip(frames, gts)]))})
    truth_cost = float(np.mean(list(meta["truth"]["seconds"].values())))
    keys_video = [tonemap(shot.channel("rgb", t)) for t in range(n)]
    keys_psnr = float(np.mean([psnr(f, g) for f, g in zip(keys_video, gts)]))
    keys_tc = float(temporal_consistency(keys_video, gts).tc)  # Cycles at the keyframes' samples on every frame
    # the passes' CPU seconds are the whole child process's (scene build and exposure probe included), over its frames
    key_cpu = float(meta["passes"]["cpu_seconds"]) / n
    return {"rows": rows, "cycles": cycles, "frames": n, "truth": {"samples": meta["truth"]["samples"], "seconds_per_frame": truth_cost},
            "keyframes": {"samples": meta["passes"]["samples"], "seconds_per_frame": key_cost, "cpu_seconds_per_frame": key_cpu,
                          "psnr_vs_truth": keys_psnr, "tc": keys_tc}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clips", default=None, help="root of bench.clips' clips (default its cache folder at --size)")
    ap.add_argument("--size", default=DEFAULT_SIZE)
    ap.add_argument("--seeds", default=None, help="clips to score, comma-separated room seeds (default: the test clips, or the "
                    "validation clip with --validation)")
    ap.add_argument("--every", default="2,4,8,16")
    ap.add_argument("--methods", default="hold,rife,classical,classical_flow,learned")
    ap.add_argument("--fill", default=None, help="folder with fill.safetensors + fill.json (default: beside the shipped weights)")
    ap.add_argument("--validation", action="store_true", help="score the validation clip (deciding settings), not the test clips")
    ap.add_argument("--weights", default=None, help="the diffusion method's model folder (default: the shipped weights)")
    ap.add_argument("--preset", default="fast", choices=["fast", "quality"], help="the diffusion method's render preset")
    args = ap.parse_args(argv)
    w, h = parse_size(args.size)
    root = Path(args.clips) if args.clips else default_root(w, h)
    split = VALIDATION_SEEDS if args.validation else TEST_SEEDS
    seeds = args.seeds or split
    wrong = set(seeds.split(",")) - set(split.split(","))
    if wrong:
        raise SystemExit(f"--seeds {','.join(sorted(wrong))}: not a {'validation' if args.validation else 'test'} clip "
                         f"(bench.clips: validation {VALIDATION_SEEDS}, test {TEST_SEEDS})")
    folders = [root / f"room_{s}" for s in seeds.split(",")]
    missing = [f for f in folders if not (f / "clip.json").is_file()]
    if missing:
        raise SystemExit(f"{missing[0]}: no clip (make it with python -m bench.clips --seeds {seeds} --size {args.size})")
    every = [int(v) for v in args.every.split(",")]
    names = args.methods.split(",")
    fill = learned_fill(args.fill) if "learned" in names else None
    if fill is None and "learned" in names:
        names.remove("learned")
    model = None
    if "diffusion" in names:
        from x2video.weights import load_model

        model = load_model(args.weights, device="cpu")
    out = {"bench": "keyframes", "description": "keyframe fills (hold, RIFE, classical, learned, diffusion) on the frames between 1 path-traced"
           " keyframe in N, against a truth rendered apart, beside Cycles on every frame",
           "command": command("keyframes", argv), "split": "validation" if args.validation else "test", "size": args.size,
           "machine": machine_info(), "fill_weights": None if fill is None else fill_sha(fill),
           "diffusion": None if model is None else {"weights": model.content_key(), "preset": args.preset},
           "clips": [score_clip(f, every, names, fill, model, args.preset) for f in folders]}
    cost = gbuffer_cost_path(f"{w}x{h}")
    if cost.is_file():
        out["gbuffer_cost"] = json.loads(cost.read_text())
    path = results_path("keyframes", result_name(args.validation, f"{w}x{h}"))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(clean_json(out), indent=1))
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
