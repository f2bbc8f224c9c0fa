"""Render speed of the tiny preset (paper Tab. acceleration "Time"): seconds per frame for DDIM-20, DDIM-4 and LCM-2,
Recursive vs Sequential sampling, per inference engine, with where the time goes, on this machine's CPU or a GPU.

Speed does not depend on the weights, so this runs the shipped weights when present, else UNTRAINED tiny ones
(and, for LCM-2, an untrained copy of the UNet standing in for the distilled one: the same network, so the same
cost per step), on a synthetic shot with all five channels made frame by frame (`SyntheticShot`: nothing held in
memory). Each configuration renders once with an empty conditioning cache (cold: a first render) and splits
its wall time (`Renderer.timing`, `x2video.render.timing.StageTimes`) into read (channels from the shot),
encode (conditioning latents), unet, decode (VAE), detail (the shading detail residual models add back), write
(the frame sink) and other; `seconds_per_frame` is the cold time less encode and detail, what a re-render with
the cache warm costs (the editor's case). Each engine (`RenderSettings.engine`) is warmed first
(`Renderer.prepare`: graphs exported or read from the disk cache, compiled, run once), and its frames are
compared with PyTorch's (max abs difference in linear RGB).

    python -m bench.render [--frames 17] [--size 320x224] [--engines torch,auto] [--device cpu|cuda] [--fp16] [--threads N]
    python -m bench.render --preset fast --frames 1000 [--quality diffusion|residual|formula] [--disk]

--preset renders that one preset (recursive) once, cold, as `x2video render` does (the Renderer keeps no
conditioning for a re-render), and records peak RSS (getrusage): the 1,000-frame memory check of issue 31.
--disk writes the synthetic shot as an EXR shot folder first and renders from it (lazy reads), and every mode
writes the frames through a `FrameSink` into a temporary EXR folder, so read and write are real I/O.

Results are merged into bench/results/render/render.json under a key naming the device (with --preset:
render_<preset>_<quality>_<frames>f.json), so CPU and GPU runs sit side by side:
    {"runs": {"<device label>": {"device", "dtype", "torch", "size": [W, H], "frames", "window",
      "weights", "load_average_before_after", "peak_rss_mb",
      "results": [{"engine", "sampler", "steps", "scheme", "seconds", "seconds_per_frame", "seconds_per_frame_cold",
      "first_frames_seconds", "windows", "unet_calls", "breakdown": {"seconds_per_frame": {stage: s}, ...},
      "max_abs_diff_vs_torch"}]}}}
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from bench.common import command, results_path
from x2video.channels import SPECS
from x2video.fields import parse_size
from x2video.io.atomic import write_json_atomic
from x2video.model.pipeline import X2VideoModel
from x2video.render.events import FramesReady, StepDone
from x2video.render.frames import FrameSink
from x2video.render.renderer import Renderer, warm_engine
from x2video.render.settings import RenderSettings, resolve, select_steps
from x2video.render.timing import StageTimes
from x2video.sampling.planner import plan
from x2video.shot import ArrayShot, Shot, ShotInfo
from x2video.tiers import registry as tiers

RESULTS = results_path("render")


class SyntheticShot(Shot):
    """Random but valid channels made per frame and channel from a seed (the content does not change the cost;
    nothing is held, so a 1,000-frame shot costs no memory)."""

    CHANNELS = ("albedo", "normal", "roughness", "metallic", "irradiance")

    def __init__(self, frames: int, width: int, height: int, seed: int = 0) -> None:
        self.seed = seed
        self.info = ShotInfo(num_frames=frames, height=height, width=width, channels=self.CHANNELS, fps=10.0, source="<synthetic bench shot>")

    def _read(self, name: str, t: int) -> np.ndarray:
        rng = np.random.default_rng([self.seed, t, self.CHANNELS.index(name)])
        h, w = self.size
        c = SPECS[name].components
        if name == "normal":
            n = rng.normal(size=(h, w, 3)).astype(np.float32)
            return n / np.linalg.norm(n, axis=-1, keepdims=True)
        return rng.uniform(0, 2 if name == "irradiance" else 1, (h, w, c)).astype(np.float32)


def synthetic_shot(frames: int, width: int, height: int, seed: int = 0) -> ArrayShot:
    """`SyntheticShot` held in memory (other benches use it)."""
    shot = SyntheticShot(frames, width, height, seed)
    return ArrayShot({n: np.stack([shot.channel(n, t) for t in range(frames)]) for n in shot.channels}, fps=10.0, source=shot.info.source)


def device_label(device: torch.device) -> str:
    if device.type == "cuda":
        return f"cuda: {torch.cuda.get_device_name(device)}"
    return f"cpu: {platform.processor() or platform.machine()}, {os.cpu_count()} cores (torch threads {torch.get_num_threads()})"


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far, MB (getrusage: KB on Linux)."""
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def time_render(renderer: Renderer, shot: Shot, settings: RenderSettings, sink_dir: Path | None, keep: bool = True) -> tuple[dict, dict[int, np.ndarray]]:
    """One cold render (empty conditioning cache) with its stage breakdown; the frames (when `keep`)."""
    first: list[float] = []
    steps = [0]
    frames: dict[int, np.ndarray] = {}
    sink = None if sink_dir is None else FrameSink(sink_dir / f"{settings.engine}-{settings.sampler}{settings.steps}-{settings.scheme}")

    def on_event(e) -> None:
        if isinstance(e, FramesReady):
            if not first:
                first.append(time.perf_counter() - t0)
            if keep:
                frames.update(e.frames)
        elif isinstance(e, StepDone):
            steps[0] += 1
        if sink is not None:
            sink(e)

    windows = renderer.plan(shot, settings)
    renderer.cache.clear()
    renderer.timing = StageTimes()
    t0 = time.perf_counter()
    renderer.render(shot, None, settings, on_event=on_event)
    if renderer.model.device.type == "cuda":
        torch.cuda.synchronize()
    seconds = time.perf_counter() - t0
    n = shot.num_frames if settings.frames is None else settings.frames[1] - settings.frames[0]
    times = renderer.timing.as_dict(n)
    cached = renderer.timing.seconds["encode"] + renderer.timing.seconds["detail"]  # what a warm cache saves
    resolved = select_steps(settings, renderer.model) if settings.preset else settings
    return {
        "engine": renderer.engine if tiers.windowed(renderer.last_tier.tier) else None,  # per-frame tiers run no UNet
        "sampler": resolved.sampler,
        "steps": resolved.steps,
        "scheme": settings.scheme,
        "quality": settings.quality,
        "seconds": round(seconds, 3),
        "seconds_per_frame_cold": round(seconds / n, 4),
        "seconds_per_frame": round((seconds - cached) / n, 4),
        "first_frames_seconds": round(first[0], 3) if first else None,
        "windows": len(windows),
        "unet_calls": steps[0],
        "breakdown": times,
    }, frames


def time_parts(model: X2VideoModel, shot: Shot, engines: list[str], window: int, repeats: int) -> dict:
    """Each part on one window of `shot`, the engines interleaved call by call (a shared machine's load hits them
    alike) and the fastest of `repeats` kept: the channel encoding of the window, one UNet call (the distilled
    UNet when the model has it) on an interpolation window and on the plan's first keyframe window
    (unet_keyN: what the editor's first network frame waits for, twice at LCM-2), the VAE decoding of the
    window's frames and of one frame; with the max abs difference of each engine's output from PyTorch's."""
    from x2video.conditioning.frame import plain_conditioning

    conds = [plain_conditioning(shot, t) for t in range(window)]
    lcm = model.has_lcm
    parts = {"encode": lambda: model.encode_frames(conds)}
    with torch.inference_mode():
        model.set_engine("torch")
        cond = model.encode_frames(conds)  # (N, C_cond, h, w)
        n, _, h, w = cond.shape
        text = model.encode_prompts([""])
        g = torch.Generator().manual_seed(0)
        x = torch.randn(n, model.latent_channels, h, w, generator=g)
        from x2video.model.api import WindowInputs

        inputs = WindowInputs(cond=cond, ref=torch.randn(n, model.latent_channels, h, w, generator=g), ref_positions=(0, n - 1), mode="interp",
                              level=1, text_global=text, text_local=text.new_zeros((0, *text.shape[1:])),
                              local_masks=torch.zeros(n, 0, *shot.size))
        parts["unet"] = lambda: model.predict_v(x, torch.tensor(749), inputs, lcm=lcm)
        parts["decode"] = lambda: torch.from_numpy(model.decode(x))
        # what the editor's first network frame costs: the plan's first (keyframe) window, and one frame decoded
        first = plan("recursive", shot.num_frames, window)[0]
        k = len(first.frames)
        key = WindowInputs(cond=cond[:k], ref=torch.zeros(k, model.latent_channels, h, w), ref_positions=first.ref_positions, mode=first.mode,
                           level=first.level, text_global=text, text_local=inputs.text_local, local_masks=torch.zeros(k, 0, *shot.size))
        parts[f"unet_key{k}"] = lambda k=k: model.predict_v(x[:k], torch.tensor(999), key, lcm=lcm)
        parts["decode1"] = lambda: torch.from_numpy(model.decode(x[:1]))
        outputs: dict[str, dict[str, torch.Tensor]] = {}
        best: dict[str, dict[str, float]] = {e: {} for e in engines}
        for e in engines:  # build and warm every graph before timing
            model.set_engine(e)
            outputs[e] = {k: f() for k, f in parts.items()}
        for _ in range(repeats):
            for k, f in parts.items():
                for e in engines:
                    model.set_engine(e)
                    t0 = time.perf_counter()
                    f()
                    dt = time.perf_counter() - t0
                    best[e][k] = min(best[e].get(k, dt), dt)
        model.set_engine("torch")
    rows = {}
    for e in engines:
        rows[e] = {"runtime": model.set_engine(e), "seconds_min": {k: round(v, 4) for k, v in best[e].items()}}
        if "torch" in outputs and e != "torch":
            rows[e]["max_abs_diff_vs_torch"] = {k: float((outputs[e][k].float() - outputs["torch"][k].float()).abs().max()) for k in parts}
            rows[e]["speedup_vs_torch"] = {k: round(best["torch"][k] / best[e][k], 2) for k in parts}
    model.set_engine("torch")
    return {"window_frames": n, "latent_size": [h, w], "unet": "lcm_unet" if lcm else "unet", "repeats": repeats, "engines": rows}


def print_breakdown(res: dict) -> None:
    b = res["breakdown"]["seconds_per_frame"]
    parts = "  ".join(f"{k} {v:.3f}" for k, v in b.items() if k != "total" and (v or k in ("unet", "decode")))
    print(f"    s/frame by stage: {parts}  (total {b['total']:.3f})", flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=17, help="shot length L (17 = one keyframe window + 4 interpolation windows at N=5)")
    ap.add_argument("--size", default="320x224", help="WxH")
    ap.add_argument("--window", type=int, default=5)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--fp16", action="store_true")
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    ap.add_argument("--engines", default="torch,auto", help="comma-separated RenderSettings.engine values to compare (default torch,auto)")
    ap.add_argument("--preset", choices=("fast", "quality"), help="render only this preset, recursive, once (the RSS check)")
    ap.add_argument("--quality", default="diffusion", choices=("diffusion", "residual", "formula"), help="the tier rendered (default diffusion)")
    ap.add_argument("--schemes", default="recursive,sequential", help="comma-separated schemes (without --preset)")
    ap.add_argument("--samplers", default="ddim-20,ddim-4,lcm-2", help="comma-separated SAMPLER-STEPS (without --preset)")
    ap.add_argument("--parts", type=int, default=0, metavar="REPEATS",
                    help="also time encode/UNet/decode of one window per engine, interleaved, fastest of REPEATS (0: off)")
    ap.add_argument("--disk", action="store_true", help="render from an EXR shot folder written first (real reads)")
    ap.add_argument("--weights", type=Path, default=None, help="model folder (default: the shipped weights in resources/, else untrained tiny)")
    ap.add_argument("--untrained", action="store_true", help="untrained tiny weights even when shipped ones exist")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    width, height = parse_size(args.size)
    device = torch.device(args.device)
    dtype = torch.float16 if args.fp16 else torch.float32
    if args.threads:
        torch.set_num_threads(args.threads)

    from x2video.weights import shipped_weights

    weights = None if args.untrained else (args.weights or shipped_weights())
    if weights is None:
        base = X2VideoModel.untrained("tiny", device=device, dtype=dtype)
        lcm = X2VideoModel(base.config, base.unet, base.vae, base.text_encoder, copy.deepcopy(base.unet), device=device, dtype=dtype, untrained=True)
        weights_label = "untrained tiny (speed only); LCM-2 uses an untrained copy of the UNet"
    else:
        lcm = X2VideoModel.from_pretrained(weights, device=device, dtype=dtype)
        if not lcm.has_lcm and args.preset is None:
            raise SystemExit(f"{weights} has no lcm_unet.safetensors; LCM-2 cannot be timed (use --untrained for speed only)")
        base = lcm
        cfg = base.config
        weights_label = f"{weights.name} (vae {list(cfg.vae.block_out_channels)}, f={cfg.vae.downsample}; unet {list(cfg.unet.block_out_channels)})"
    tmp = tempfile.TemporaryDirectory(prefix="x2video-bench-render-")
    shot: Shot = SyntheticShot(args.frames, width, height)
    if args.disk:
        from x2video.io import load_shot
        from x2video.io.shotdir import write_shot_folder

        shot = load_shot(write_shot_folder(shot, Path(tmp.name) / "shot"))
    sink_dir = Path(tmp.name) / "out"
    engines = [e.strip() for e in args.engines.split(",") if e.strip()]
    # --preset renders as `x2video render` does: nothing retained for a re-render (Renderer retain=False)
    ddim = Renderer(base, retain=args.preset is None)
    renderers = {"ddim": ddim, "lcm": Renderer(lcm, cache=ddim.cache, retain=args.preset is None)}  # same VAE: one conditioning cache
    load_before = os.getloadavg()
    results = []
    if args.preset:
        configs = [RenderSettings(preset=args.preset, window=args.window, quality=args.quality, engine=e, base="off") for e in engines]
    else:
        configs = [RenderSettings(sampler=sampler, steps=steps, window=args.window, scheme=scheme, engine=e, quality=args.quality, base="off")
                   for e in engines for scheme in args.schemes.split(",") for sampler, steps in
                   [(c.split("-")[0], int(c.split("-")[1])) for c in args.samplers.split(",") if c]]
    parts = None
    if args.parts:
        parts = time_parts(lcm, shot, engines, args.window, args.parts)
        for e, row in parts["engines"].items():
            print(f"parts {e} ({row['runtime']}): " + "  ".join(f"{k} {v:.3f} s" for k, v in row["seconds_min"].items())
                  + (f"; speed-up {row['speedup_vs_torch']}, max |diff| {row['max_abs_diff_vs_torch']}" if "speedup_vs_torch" in row else ""), flush=True)
    reference: dict[tuple, dict[int, np.ndarray]] = {}
    warmed: set[tuple] = set()
    for s in configs:
        r = renderers[select_steps(s, base).sampler if s.preset else s.sampler]
        if (s.engine, s.sampler, s.preset, s.scheme) not in warmed and tiers.windowed(s.quality):
            warmed.add((s.engine, s.sampler, s.preset, s.scheme))  # graphs exported/compiled and run once, outside the timing
            valid = resolve(s, r.model)
            r.render(shot, None, RenderSettings(**{**valid.__dict__, "frames": (0, min(args.frames, args.window)), "steps": 1, "preset": None}))
            warm_engine(r, r.plan(shot, valid), valid, (-(-height // base.downsample), -(-width // base.downsample)))
        keep = args.frames <= 65
        res, frames = time_render(r, shot, s, sink_dir, keep=keep)
        key = (res["sampler"], res["steps"], res["scheme"], res["quality"])
        if res["engine"] == "torch" and keep:
            reference[key] = frames
        elif key in reference and keep:
            res["max_abs_diff_vs_torch"] = float(max(np.abs(frames[f] - reference[key][f]).max() for f in frames))
        res["peak_rss_mb_so_far"] = peak_rss_mb()
        results.append(res)
        diff = f", max |diff| vs torch {res['max_abs_diff_vs_torch']:.2e}" if "max_abs_diff_vs_torch" in res else ""
        print(f"{str(res['engine']):8s} {res['scheme']:10s} {res['sampler']}-{res['steps']:<3d} {res['quality']}: {res['seconds_per_frame']:.3f} s/frame warm, "
              f"{res['seconds_per_frame_cold']:.3f} cold ({res['seconds']:.1f} s, {res['windows']} windows, first frames after "
              f"{res['first_frames_seconds']} s{diff}); peak RSS {res['peak_rss_mb_so_far']:.0f} MB", flush=True)
        print_breakdown(res)

    label = device_label(device) + ("" if weights is None else " shipped")
    out = args.out or (results_path("render", f"render_{args.preset}_{args.quality}_{args.frames}f") if args.preset else RESULTS)
    data = json.loads(out.read_text()) if out.is_file() else {"runs": {}}
    data["format"], data["command"] = "x2video-render-speed", command("render")
    data.setdefault("runs", {})[label] = {
        "command": command("render"),
        "device": label,
        "dtype": str(dtype).replace("torch.", ""),
        "torch": torch.__version__,
        "size": [width, height],
        "frames": args.frames,
        "window": args.window,
        "weights": weights_label,
        "shot": "EXR shot folder (lazy reads)" if args.disk else "synthetic, made per frame",
        "note": "seconds_per_frame_cold: one render with an empty conditioning cache; seconds_per_frame: the same less its encode "
        "and detail stages (what a re-render with the cache warm costs); breakdown: Renderer.timing per stage",
        "load_average_before_after": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
        "peak_rss_mb": peak_rss_mb(),
        "parts": parts,
        "results": results,
    }
    write_json_atomic(out, data)
    tmp.cleanup()
    print(f"peak RSS {peak_rss_mb():.0f} MB; wrote {out}")


if __name__ == "__main__":
    main()
