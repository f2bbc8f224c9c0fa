"""The speed-accuracy chart: seconds per frame (log) against PSNR and TC on path-traced test rooms, for every way
of making the picture: the formula, tier 1, the diffusion sampler's step counts and schemes, and Cycles itself.

    python -m bench.pareto --data DATA/pt160,DATA/pt320 --sizes 160x112,320x224 [--rooms 2 --frames 4] (or --rooms 2,1: per size)
        [--methods formula,residual,ddim-20,...,cycles-64] [--reference-samples 128] [--threads 2]
    python -m bench.pareto ...the same data, sizes, rooms, frames... --methods residual --merge docs/pareto.json
    python -m bench.pareto --data DATA/pt160 --sizes 160x112 --rooms 1 --frames 8 --methods lcm-2,lcm-2-seq \
        --merge docs/pareto.json --section "long shot"

`--merge` reruns some methods into an existing result (new weights, a quieter machine): their rows replace the rows
of the same method and size, the others stay, and every row names the run that measured it (`runs`: command, commit,
date, load, weights digest), so a chart of several runs says so. It is refused unless the run measures the same
thing: the same data folders, shots and frames (names and a digest of the channels), the same ground truth (kind,
samples, seed; the reference render's digest, else the deterministic formula row re-scored against the kept one).
`--section NAME` keeps rows of other shots or frames (recursive against sequential sampling needs a shot longer than
a window) in a section of their own, drawn below the main panels; the editor reads the main rows.

For each size, the first `--rooms` finished shots of that size among the `--data` folders (DATA/<split>/<shot>/,
from `x2video dataset make --renderer cycles`) and their first `--frames` frames. Methods:

    formula          tier 0: albedo x irradiance (RenderSettings.quality 'formula')
    residual         tier 1: one pass of the shipped tier-1 net (quality 'residual')
    ddim-S, lcm-S    tier 2: the video diffusion sampler with S steps, Recursive Sampling
    ddim-S-seq, ...  the same with sequential sampling (skipped, and said so, where the two plans are the same
                     windows: shots no longer than one window)
    cycles-S         Cycles at S samples per pixel, OpenImageDenoise'd: the room rebuilt from its seed
                     (`x2video.cycles.shot.beauty_scene`: same scene, cameras, light gain) and only the picture
                     rendered, as a Blender user would, in a Blender process of its own, timed in this run

Ground truth: with `--reference-samples R` (default 128) the bench renders its own reference of the same frames
with Cycles at R samples, denoised, with another noise seed than the rows (the data sets' frames were rendered
at fewer samples, often 32, with the rows' seed: a Cycles row at 64 samples is not to be scored against them);
with 0 it scores against the data set's frames (N samples, OpenImageDenoise'd) and says so. Every row is also
scored against the data set's frames (`psnr_dataset`). Scoring is `bench.ptscore` (as bench.pathtraced):
PSNR/SSIM on display images in the shot's units, TC = warping error over the ground truth's (DIS flow).

Seconds per frame: wall time of the render of the shot's frames over their count; the model loaded, one
untimed warm-up per size, each method with a fresh conditioning cache (it pays its own encoding); Cycles:
the render call per frame (scene sync, path tracing, denoising, writing the EXR), the scene built beforehand.

Writes docs/pareto.json (`--out`), docs/pareto.png (two panels, matplotlib) and bench/results/pareto/pareto.md.
The editor's speed-vs-accuracy chart reads docs/pareto.json and marks the setting of the current render.
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import multiprocessing as mp
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bench.common import clean_json, command, results_path
from bench.ptscore import display, render_timed, score, shot_dirs, truth
from x2video.cli.fields import add_fields, from_args
from x2video.sampling import tiers
from x2video.sampling.tier import Tier

DOCS = Path(__file__).resolve().parents[1] / "docs"
METHODS = ("formula", "residual", "ddim-1", "ddim-2", "ddim-4", "ddim-8", "ddim-20", "lcm-1", "lcm-2", "lcm-4",
           "ddim-4-seq", "ddim-20-seq", "lcm-2-seq", "cycles-4", "cycles-16", "cycles-64")
#: within this many dB of the best PSNR counts as "as good" for the summary's fastest setting
NEAR_BEST_DB = 0.5


@dataclass
class ParetoOptions:
    """What `python -m bench.pareto` measures (flags via `x2video.cli.fields`)."""

    data: str = ""
    """Data set folder(s), comma-separated, each DATA/<split>/<shot>/ of path-traced shots with rgb ground truth;
    the shots of each size come from the folders that have shots of that size."""
    split: str = "test"
    """Split folder inside each data set ('' for a folder of shots)."""
    sizes: str = "160x112,320x224"
    """Sizes WxH to measure, comma-separated; each needs shots of that size in --data."""
    rooms: tuple[int, ...] = (2,)
    """First K finished shots per size: one K for every size, or one per --sizes entry (e.g. 2,1)."""
    frames: tuple[int, ...] = (4,)
    """First T frames of each shot (at least 2 for TC): one T for every size, or one per --sizes entry."""
    methods: str = ",".join(METHODS)
    """Rows, comma-separated: formula, residual, ddim-S, lcm-S (add -seq for sequential sampling), cycles-S."""
    reference_samples: int = 128
    """Cycles samples of the bench's own ground truth (denoised, another noise seed); 0: the data set's frames."""
    threads: int = 2
    """torch CPU threads and Cycles threads (the same for both, so that the seconds compare)."""
    clock: Literal["cpu", "wall"] = "cpu"
    """The seconds the chart, the summary and the editor use (each row's seconds_per_frame): 'cpu' = CPU seconds per
    frame of the rendering process, all its threads (steady when other jobs share the machine); 'wall' = wall
    seconds per frame (what a user waits, on an otherwise idle machine). Both are in the JSON."""
    weights: str = ""
    """Model folder (default: the shipped weights)."""
    out: str = ""
    """Result JSON (default docs/pareto.json; the PNG beside it, the Markdown in bench/results/pareto/)."""
    png: bool = True
    """Draw the PNG (needs matplotlib: pip install 'x2video-studio[bench]')."""
    replot: str = ""
    """Measure nothing: redraw the PNG and the Markdown from this result JSON (e.g. docs/pareto.json)."""
    merge: str = ""
    """Merge this run into that result (e.g. docs/pareto.json) instead of writing one of its own: its rows replace the rows
    of the same method and size, the others are kept, and each row names the run that measured it ('runs': command,
    commit, date, load, weights digest). Refused unless the data, shots, frames and ground truth are the same (checked
    before Cycles runs and again after the reference: its digest, else formula re-scored against the kept formula row;
    formula is measured first). Written to --out (default: the file merged into)."""
    section: str = ""
    """With --merge: a section of the chart of its own (e.g. 'long shot': other shots, frames, reference), kept under
    'sections' beside the main rows (which the editor reads) and drawn below them; merging into it again checks it alike."""
    from_result: str = ""
    """With --merge: measure nothing; merge this finished result of bench.pareto (a run written with --out) instead."""


@dataclass(frozen=True)
class Method:
    key: str  # as given: "ddim-20-seq"
    kind: str  # a tier's name (formula | residual | diffusion) or cycles
    sampler: str = ""
    steps: int = 0
    scheme: str = "recursive"
    samples: int = 0

    @property
    def tier(self) -> Tier | None:
        """The tier whose renders this method measures (None: Cycles)."""
        return None if self.kind == "cycles" else tiers.get(self.kind)

    @property
    def windowed(self) -> bool:
        """The sampler's windows (the diffusion tier): its sampler, steps and scheme name the method."""
        return tiers.windowed(self.kind)

    @property
    def needs_model(self) -> bool:
        tier = self.tier
        return tier is not None and tier.needs_model

    @property
    def label(self) -> str:
        if self.kind == "cycles":
            return f"Cycles {self.samples} spp + OIDN"
        if self.windowed:
            return f"{self.sampler.upper()}-{self.steps}" + (" sequential" if self.scheme == "sequential" else "")
        return FAMILY_NAMES.get(self.kind, self.kind)

    @property
    def family(self) -> str:
        """Points joined by a line in the chart: the DDIM steps, the LCM steps, the Cycles samples."""
        if self.windowed:
            return f"{self.sampler}-{self.scheme}"
        return self.kind


def parse_method(text: str) -> Method:
    """'formula', 'residual', 'ddim-20', 'lcm-2-seq', 'cycles-64' -> Method; a clear error otherwise."""
    t = text.strip().lower()
    if t in tiers.TIERS and not tiers.windowed(t):  # a per-frame tier is named by itself
        return Method(t, t)
    m = re.fullmatch(r"(ddim|lcm)-(\d+)(-seq)?", t)
    if m:
        return Method(t, "diffusion", m.group(1), int(m.group(2)), "sequential" if m.group(3) else "recursive")
    m = re.fullmatch(r"cycles-(\d+)", t)
    if m:
        return Method(t, "cycles", samples=int(m.group(1)))
    raise ValueError(f"--methods: unknown method {text!r} (formula, residual, ddim-S, lcm-S, ddim-S-seq, lcm-S-seq, cycles-S)")


def per_size(values: tuple[int, ...], sizes: list, flag: str) -> list[int]:
    """One value per size from a flag holding one value or one per size."""
    vals = list(values) * len(sizes) if len(values) == 1 else list(values)
    if len(vals) != len(sizes) or min(vals, default=0) < 1:
        raise SystemExit(f"{flag}: one value of at least 1, or one per --sizes entry ({len(sizes)}); got {','.join(map(str, values))}")
    return vals


def parse_sizes(text: str) -> list[tuple[int, int]]:
    from x2video.cli.args import size_arg

    return [tuple(size_arg(s)) for s in text.split(",") if s.strip()]  # (W, H)


# --------------------------------------------------------------------------------------------- data
def shots_by_size(folders: list[Path], split: str) -> dict[tuple[int, int], list[Path]]:
    """(W, H) -> finished shot folders of that size (sorted), over every data set folder."""
    out: dict[tuple[int, int], list[Path]] = {}
    for f in folders:
        root = f / split if split else f
        if not root.is_dir():
            raise SystemExit(f"--data {f}: no folder {root}")
        for d in shot_dirs(root):
            info = json.loads((d / "shot.json").read_text())
            out.setdefault((int(info["width"]), int(info["height"])), []).append(d)
    return {k: sorted(v, key=lambda p: (p.name, str(p))) for k, v in out.items()}


def cycles_job(shot_dir: Path, frames: int) -> dict | None:
    """What a Cycles process needs to rebuild this room (None: not a procedural room of `x2video.cycles`)."""
    from x2video.io.metadata import parse_cameras_json

    info = json.loads((shot_dir / "shot.json").read_text())
    extra = info.get("extra", {})
    if "room_seed" not in extra or "light_gain" not in extra or not (shot_dir / "cameras.json").is_file():
        return None
    poses = parse_cameras_json(shot_dir / "cameras.json", int(info["num_frames"]))
    return {"dir": str(shot_dir), "seed": int(extra["room_seed"]), "gain": float(extra["light_gain"]),
            "poses": [(np.asarray(p.cam_to_world, float).tolist(), p.fov_y_deg) for p in poses[:frames]],
            "width": int(info["width"]), "height": int(info["height"]), "samples": extra.get("samples"),
            "version": 3 if str(extra.get("generator", "")).endswith("v3") else 2}


def frames_sha256(shots: list, nframes: list[int]) -> str:
    """A digest of the frames a run renders and scores: every channel the model reads and the data set's rgb, per
    shot and frame (float32 bytes), so that a merge can tell the same data from data rebuilt under the same names."""
    import hashlib

    h = hashlib.sha256()
    for s, n in zip(shots, nframes):
        for t in range(n):
            for c in ("albedo", "normal", "roughness", "metallic", "irradiance", "rgb"):
                if s.has(c):
                    h.update(c.encode())
                    h.update(np.ascontiguousarray(s.channel(c, t), np.float32).tobytes())
    return h.hexdigest()


def images_sha256(shots: list[list[np.ndarray]]) -> str:
    """A digest of display images at 8 bits (a reference render: exact where Cycles and OIDN repeat themselves)."""
    import hashlib

    h = hashlib.sha256()
    for frames in shots:
        for f in frames:
            h.update(np.round(np.clip(f, 0, 1) * 255).astype(np.uint8).tobytes())
    return h.hexdigest()


# --------------------------------------------------------------------------------------------- Cycles (own process)
def _quiet() -> None:
    """Blender prints a line per tile and pass to the C stdout: send it to /dev/null in the worker."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)


def _cycles_worker(jobs: list[dict], samples: list[int], reference: int, threads: int) -> list[dict]:
    """In a Blender process: per job, {samples: (frames, wall seconds, CPU seconds of the process)} for each count
    (seed 0, as the data sets), the reference frames (seed 1) when `reference`, and the scene's build seconds."""
    from x2video.cycles.shot import beauty_scene, render_beauty
    from x2video.shot import CameraPose

    out = []
    warm = False
    for job in jobs:
        poses = [CameraPose(np.array(m, float), fov) for m, fov in job["poses"]]
        t0 = time.perf_counter()
        scene = beauty_scene(job["seed"], poses, job["width"], job["height"], job["gain"], threads=threads, version=job.get("version", 2))
        build = time.perf_counter() - t0
        if not warm:  # kernels and OIDN load on the first render of the process: untimed
            render_beauty(scene, 0, 1)
            warm = True
        res: dict[str, Any] = {"build_seconds": build, "rows": {}}
        for s in samples:
            frames, secs = [], []
            c0 = time.process_time()
            for t in range(len(poses)):
                img, sec = render_beauty(scene, t, s, seed=0)
                frames.append(img)
                secs.append(sec)
            res["rows"][s] = (frames, sum(secs), time.process_time() - c0)
        if reference:
            res["reference"] = [render_beauty(scene, t, reference, seed=1)[0] for t in range(len(poses))]
        out.append(res)
    return out


def run_cycles(jobs: list[dict], samples: list[int], reference: int, threads: int) -> list[dict]:
    """`_cycles_worker` in a spawned process (bpy wants a process of its own)."""
    with mp.get_context("spawn").Pool(1, initializer=_quiet) as pool:
        return pool.apply(_cycles_worker, (jobs, samples, reference, threads))


def bpy_available() -> str | None:
    """None when Blender's Python module can be imported, else why not."""
    import importlib.util

    try:
        return None if importlib.util.find_spec("bpy") is not None else "bpy is not installed (pip install 'x2video-studio[cycles]')"
    except (ImportError, ValueError) as exc:
        return f"bpy: {exc}"


# --------------------------------------------------------------------------------------------- the model's rows
def diffusion_settings(m: Method, frames: int):
    from x2video.sampling.events import RenderSettings

    if m.windowed:
        return RenderSettings(quality=m.kind, sampler=m.sampler, steps=m.steps, scheme=m.scheme, frames=(0, frames))
    return RenderSettings(quality=m.kind, frames=(0, frames))


def same_plan(model: Any, shot: Any, m: Method, frames: int) -> bool:
    """Whether sequential sampling of `m` runs exactly the windows recursive sampling does (short shots)."""
    from x2video.sampling.renderer import Renderer

    r = Renderer(model)
    s = diffusion_settings(m, frames)
    key = lambda plan: [(w.frames, w.generate, w.refs) for w in plan]  # noqa: E731 - 'key' and 'seq' windows sample alike
    return key(r.plan(shot, s)) == key(r.plan(shot, dataclasses.replace(s, scheme="recursive")))


def warm_up(model: Any, shots: list, nframes: list[int], methods: list[Method]) -> None:
    """Untimed renders of the frames the rows render, one per network and scheme the methods use (1 step): first-call
    costs stay out of the rows, among them the diffusion engine's graphs, which are exported and compiled per window
    size and window kind (`x2video.model.engine`: a 2-frame warm-up left a 3-, 4- or 5-frame window's to the first row)."""
    from x2video.sampling.renderer import Renderer

    kinds = {(m.kind, m.sampler, m.scheme if m.windowed else "") for m in methods if m.needs_model}
    firsts: dict[int, Any] = {}
    for s, n in zip(shots, nframes):
        firsts.setdefault(n, s)  # one shot per frame count: the windows depend on nothing else
    for kind, sampler, scheme in sorted(kinds):
        m = Method("warm", kind, sampler, 1, scheme) if tiers.windowed(kind) else Method("warm", kind)
        for n, shot in firsts.items():
            render_timed(Renderer(model), shot, diffusion_settings(m, n))


# --------------------------------------------------------------------------------------------- the bench
def measure(opts: ParetoOptions, argv: list[str] | None, on_partial: Any = None) -> dict:
    """The result (see the module docstring); `on_partial(result)` after each row, with "complete": False."""
    import torch

    from x2video.io import load_shot
    from x2video.sampling.renderer import Renderer

    if not opts.data:
        raise SystemExit("--data: give the path-traced data set folder(s)")
    torch.set_num_threads(opts.threads)
    methods = [parse_method(t) for t in opts.methods.split(",") if t.strip()]
    if not methods:
        raise SystemExit("--methods: none given")
    folders = [Path(p) for p in opts.data.split(",") if p.strip()]
    found = shots_by_size(folders, opts.split)
    sizes = parse_sizes(opts.sizes)
    rooms, frames = per_size(opts.rooms, sizes, "--rooms"), per_size(opts.frames, sizes, "--frames")
    missing = [s for s in sizes if not found.get(s)]
    if missing:
        have = ", ".join(f"{w}x{h} ({len(v)})" for (w, h), v in sorted(found.items())) or "none"
        raise SystemExit(f"--sizes: no finished shot of {', '.join(f'{w}x{h}' for w, h in missing)} in --data {opts.data}"
                         f" (split {opts.split!r}); sizes there: {have}")
    model = None
    if any(m.needs_model for m in methods):
        from x2video.weights import load_model

        model = load_model(opts.weights or None)
        model.encode_prompts([""])  # the text encoder loads before any clock runs
    cyc = [m for m in methods if m.kind == "cycles"]
    no_bpy = bpy_available() if (cyc or opts.reference_samples) else None
    load0 = os.getloadavg()
    t_all = time.perf_counter()
    rows: list[dict] = []
    unavailable: list[dict] = []
    ground_truth: dict[str, Any] = {}

    def result(complete: bool) -> dict:
        return _result(opts, argv, model, folders, sizes, rooms, frames, ground_truth, rows, unavailable, load0, t_all, complete)
    for (w, h), n_rooms, n_frames in zip(sizes, rooms, frames):
        dirs = found[(w, h)][:n_rooms]
        shots = [load_shot(d) for d in dirs]
        nframes = [min(n_frames, s.num_frames) for s in shots]
        print(f"{w}x{h}: {len(shots)} shot(s) ({', '.join(d.name for d in dirs)}), {nframes} frames", file=sys.stderr, flush=True)
        gts = [truth(s, n) for s, n in zip(shots, nframes)]
        # Cycles first (its process is gone before the model's clocks run)
        jobs = [cycles_job(d, n) for d, n in zip(dirs, nframes)]
        cycles_res: list[dict | None] = [None] * len(shots)
        why_no_cycles = no_bpy or (None if all(jobs) else
                                   f"{dirs[jobs.index(None)]} is not a procedural Cycles room (no room_seed/light_gain in shot.json)")
        want_ref = opts.reference_samples if not why_no_cycles else 0
        samples_gt = sorted({j["samples"] for j in jobs if j and j.get("samples")}) if any(jobs) else []
        size_key = f"{w}x{h}"
        if want_ref:
            ground_truth[size_key] = {"kind": "bench reference", "samples": want_ref, "denoise": "OpenImageDenoise", "seed": 1,
                                      "note": f"Cycles at {want_ref} spp, denoised, rendered by this run with another noise seed than "
                                              "the Cycles rows; the data set's frames "
                                              f"({'/'.join(map(str, samples_gt)) or '?'} spp, denoised) give psnr_dataset"}
        else:
            why = "--reference-samples 0" if not opts.reference_samples else f"no bench reference: {why_no_cycles}"
            ground_truth[size_key] = {"kind": "data set frames", "samples": samples_gt, "denoise": "OpenImageDenoise",
                                      "note": f"the data set's frames at {'/'.join(map(str, samples_gt)) or '?'} spp, denoised ({why})"
                                              + ("; Cycles rows at more samples than these are scored against a noisier reference"
                                                 if any(m.samples > max(samples_gt or [0]) for m in cyc) else "")}
        # what a merge checks (--merge): the same shots, frames and inputs (now, before Cycles runs), the same reference
        ground_truth[size_key].update(shots=[d.name for d in dirs], frames=nframes, data_sha256=frames_sha256(shots, nframes))
        if on_partial is not None:
            on_partial(result(False))
        if (cyc or want_ref) and not why_no_cycles:
            t0 = time.perf_counter()
            cycles_res = run_cycles(jobs, [m.samples for m in cyc], want_ref, opts.threads)  # type: ignore[assignment]
            print(f"{w}x{h}: Cycles done in {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        refs = [display(r["reference"]) for r in cycles_res] if want_ref else gts  # type: ignore[index]
        ground_truth[size_key]["reference_sha256"] = images_sha256(refs)
        if cyc and why_no_cycles:
            unavailable += [{"method": m.key, "size": [w, h], "reason": why_no_cycles} for m in cyc]
        if model is not None:
            warm_up(model, shots, nframes, methods)
        for m in methods:
            per_shot, secs_total, cpu_total, frames_total = [], 0.0, 0.0, 0
            engine = None  # what ran the diffusion tier's networks (RenderSettings.engine 'auto' resolved)
            if m.kind == "cycles":
                if why_no_cycles:
                    continue
                outs = [(*r["rows"][m.samples], 1.0) for r in cycles_res]  # type: ignore[index]
            else:
                if m.scheme == "sequential" and all(same_plan(model, s, m, n) for s, n in zip(shots, nframes)):
                    unavailable.append({"method": m.key, "size": [w, h], "reason": f"the same windows as recursive sampling at "
                                        f"{max(nframes)} frames (a shot no longer than one window)"})
                    continue
                outs = []
                for s, n in zip(shots, nframes):
                    if not m.needs_model:
                        c0 = time.process_time()
                        fr, sec = render_timed(Renderer(None), s, diffusion_settings(m, n))  # tier 0 needs no model
                    else:
                        renderer = Renderer(model)
                        c0 = time.process_time()
                        fr, sec = render_timed(renderer, s, diffusion_settings(m, n))
                        if m.windowed:
                            engine = getattr(renderer, "engine", None)
                    outs.append((fr, sec, time.process_time() - c0, float(s.info.irradiance_scale)))
            for (fr, sec, cpu, scale), s, n, ref, gt in zip(outs, shots, nframes, refs, gts):
                disp = display(fr, scale)
                sc, sc_ds = score(disp, ref), score(disp, gt)
                per_shot.append({"shot": Path(str(s.info.source)).name, "frames": n, "seconds": sec, "cpu_seconds": cpu, **sc,
                                 "psnr_dataset": sc_ds["psnr"], "tc_dataset": sc_ds["tc"]})
                secs_total += sec
                cpu_total += cpu
                frames_total += n
            row = {"name": f"{m.label} {w}x{h}", "method": m.key, "label": m.label, "kind": m.kind, "family": m.family, "size": [w, h],
                   "sampler": m.sampler or None, "steps": m.steps or None, "scheme": m.scheme if m.windowed else None,
                   "samples": m.samples or None, "engine": engine, "wall_seconds_per_frame": secs_total / max(frames_total, 1),
                   "cpu_seconds_per_frame": cpu_total / max(frames_total, 1), "frames": frames_total,
                   **{k: _mean([p[k] for p in per_shot]) for k in ("psnr", "ssim", "tc", "psnr_dataset", "tc_dataset")},
                   "per_shot": per_shot}
            row["seconds_per_frame"] = row[f"{opts.clock}_seconds_per_frame"]
            rows.append(row)
            if on_partial is not None:
                on_partial(result(False))
            print(f"{row['name']:>36}: {row['wall_seconds_per_frame']:8.3f} s/frame ({row['cpu_seconds_per_frame']:8.3f} CPU s)  "
                  f"PSNR {row['psnr']:6.2f}  TC {row['tc']}", file=sys.stderr, flush=True)
    return result(True)


def _result(opts: ParetoOptions, argv: list[str] | None, model: Any, folders: list[Path], sizes: list, rooms: list[int], frames: list[int],
            ground_truth: dict, rows: list[dict], unavailable: list[dict], load0: tuple, t_all: float, complete: bool) -> dict:
    from x2video.eval.machine import machine_info
    from x2video.io.paths import portable_path
    from x2video.weights import shipped_weights

    weights = portable_path(opts.weights) if opts.weights else f"shipped ({portable_path(shipped_weights() or '?')})"
    return {"format": "x2video-pareto", "complete": complete, "command": command("pareto", argv),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "weights_sha256": weights_digest(Path(opts.weights) if opts.weights else shipped_weights()) if model is not None else None,
            "machine": machine_info(model.device if model is not None else "cpu"),
            "threads": opts.threads, "clock": opts.clock, "load_average_start": [round(v, 2) for v in load0],
            "load_average_end": [round(v, 2) for v in os.getloadavg()], "weights": weights,
            "residual_net": bool(model is not None and model.residual_net is not None), "has_lcm": bool(model is not None and model.has_lcm),
            "data": [portable_path(f) for f in folders], "split": opts.split,
            "rooms": {f"{w}x{h}": k for (w, h), k in zip(sizes, rooms)}, "frames": {f"{w}x{h}": t for (w, h), t in zip(sizes, frames)},
            "ground_truth": ground_truth,
            "note": "PSNR/SSIM on tonemap (clip, sRGB) in the shot's units against ground_truth; psnr_dataset against the data set's "
                    "frames; TC = warping error / ground truth's (DIS flow); wall_seconds_per_frame = wall time of the render over its "
                    "frames, cpu_seconds_per_frame = the rendering process's CPU seconds (all threads) over its frames "
                    f"({opts.threads} threads for torch and Cycles), model loaded and warmed up, each row paying its own conditioning "
                    f"encoding; seconds_per_frame = the {opts.clock} figure (the chart's x)",
            "rows": rows, "unavailable": unavailable, "summary": summarise(rows), "wall_seconds": time.perf_counter() - t_all}


def weights_digest(folder: Path | None) -> dict[str, str] | None:
    """{file: first 16 hex digits of its SHA-256} for the model folder's top-level files (which tier-1 net, which
    diffusion weights measured a row: the folder's name stays when its weights are retrained)."""
    import hashlib

    if folder is None or not Path(folder).is_dir():
        return None
    return {f.name: hashlib.sha256(f.read_bytes()).hexdigest()[:16] for f in sorted(Path(folder).iterdir())
            if f.is_file() and f.suffix in (".safetensors", ".json", ".pt", ".onnx")}


def _mean(vals: list) -> float | None:
    v = [x for x in vals if x is not None and math.isfinite(x)]
    return float(np.mean(v)) if v else None


def summarise(rows: list[dict]) -> dict:
    """Per size: the best PSNR among the model's settings (formula, tier 1, sampler), the fastest setting within
    NEAR_BEST_DB of it, and its speed-up over DDIM-20 (recursive) and over Cycles at 64 samples, in wall seconds
    and in CPU seconds (`_cpu`: less sensitive to other jobs on a shared machine)."""
    out: dict[str, Any] = {}
    for size in sorted({tuple(r["size"]) for r in rows}):
        rs = [r for r in rows if tuple(r["size"]) == size]
        ours = [r for r in rs if r["kind"] != "cycles" and r["psnr"] is not None]
        if not ours:
            continue
        best = max(ours, key=lambda r: r["psnr"])
        fast = min((r for r in ours if r["psnr"] >= best["psnr"] - NEAR_BEST_DB), key=lambda r: r["seconds_per_frame"])
        ddim20 = next((r for r in rs if r["method"] == "ddim-20"), None)
        c64 = next((r for r in rs if r["method"] == "cycles-64"), None)
        s = {"best": best["label"], "best_psnr": best["psnr"], "fastest_near_best": fast["label"], "fastest_method": fast["method"],
             "fastest_psnr": fast["psnr"], "fastest_wall_seconds_per_frame": fast["wall_seconds_per_frame"],
             "fastest_cpu_seconds_per_frame": fast["cpu_seconds_per_frame"], "near_best_db": NEAR_BEST_DB,
             "fastest_by": "seconds_per_frame (the run's clock)"}
        for key, ref in (("speedup_over_ddim20", ddim20), ("speedup_over_cycles64", c64)):
            for clock in ("wall", "cpu"):
                a, b = (ref or {}).get(f"{clock}_seconds_per_frame"), fast.get(f"{clock}_seconds_per_frame")
                s[f"{key}_{clock}"] = a / b if a and b else None
        if c64 is not None:
            s["cycles64_psnr"] = c64["psnr"]
        if any(r.get("run") is not None for r in (fast, ddim20, c64) if r):  # a merged result: which run timed each
            s["runs"] = {k: (r or {}).get("run") for k, r in (("fastest", fast), ("ddim20", ddim20), ("cycles64", c64))}
        out[f"{size[0]}x{size[1]}"] = s
    return out


# --------------------------------------------------------------------------------------------- merging runs
#: the keys of a section of the chart: the main section is the result's top level, the others under "sections"
SECTION_KEYS = ("data", "split", "rooms", "frames", "ground_truth", "rows", "unavailable", "summary")
#: a re-scored formula row must agree with the kept one within these (the formula is deterministic: a difference
#: means other frames or another reference)
PROBE_TOLERANCE = {"psnr": 0.02, "ssim": 0.0005, "psnr_dataset": 0.02, "tc": 0.01}


class MergeError(SystemExit):
    """A run that does not measure the same frames against the same ground truth as the result it would merge into."""


def _run_record(res: dict, run_id: int, section: str, origin: Path | None = None) -> dict:
    """What produced some rows: command, commit, date, load, weights, machine (a result of before runs were recorded:
    its date is the commit date of its file, where git knows it)."""
    rec = {"id": run_id, "section": section, "command": res.get("command"), "commit": (res.get("machine") or {}).get("git_commit"),
           "date": res.get("date"), "load_average_start": res.get("load_average_start"), "load_average_end": res.get("load_average_end"),
           "wall_seconds": res.get("wall_seconds"), "weights": res.get("weights"), "weights_sha256": res.get("weights_sha256"),
           "threads": res.get("threads"), "clock": res.get("clock"), "complete": res.get("complete", True), "machine": res.get("machine"),
           "methods": list(dict.fromkeys(r["method"] for r in res.get("rows", []))),
           "engines": sorted({r["engine"] for r in res.get("rows", []) if r.get("engine")}) or None}
    if rec["date"] is None and origin is not None:
        rec["date"], rec["date_note"] = _commit_date(origin), f"not recorded by the run: the last commit date of {origin.name}"
    return rec


def _commit_date(path: Path) -> str | None:
    import subprocess

    try:
        out = subprocess.run(["git", "log", "-1", "--format=%cI", "--", path.name], cwd=path.parent, capture_output=True, text=True, timeout=30)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def _section(res: dict, name: str) -> dict | None:
    if not name:
        return {k: res.get(k) for k in SECTION_KEYS} if res.get("rows") is not None else None
    return (res.get("sections") or {}).get(name)


def _shots_of(sec: dict, size: str) -> tuple[list[str], list[int]]:
    """(shot names, frames per shot) a section measured at `size`: recorded in its ground truth, or (results from
    before that was recorded) read off its rows."""
    g = (sec.get("ground_truth") or {}).get(size) or {}
    if "shots" in g:
        return list(g["shots"]), list(g["frames"])
    for r in sec.get("rows") or []:
        if f"{r['size'][0]}x{r['size'][1]}" == size and r.get("per_shot"):
            return [p["shot"] for p in r["per_shot"]], [p["frames"] for p in r["per_shot"]]
    return [], []


def merge_problems(old: dict, new: dict, section: str, where: str = "the result merged into") -> tuple[list[str], dict[str, str]]:
    """Why `new` (a run of this bench) cannot be merged into section `section` of `old` (empty: it can), and per size how
    the ground truth was found the same. Checked: clock and threads; data folders and split; per size measured by both,
    the shots, their frames, the ground truth's kind, samples and seed, the digest of the inputs and the data set's
    frames (where both recorded it), and the reference: its digest, else a re-scored formula row against the kept one."""
    problems: list[str] = []
    checks: dict[str, str] = {}
    for key in ("clock", "threads"):
        if old.get(key) != new.get(key):
            problems.append(f"--{key}: this run has {new.get(key)!r}, {where} {old.get(key)!r} (its seconds would not compare)")
    o, n = _section(old, section), _section(new, "")
    if o is None or n is None:
        return problems, checks
    if sorted(o.get("data") or []) != sorted(n.get("data") or []) or o.get("split") != n.get("split"):
        problems.append(f"--data/--split: this run read {n.get('data')} ({n.get('split')!r}), {where} {o.get('data')} ({o.get('split')!r})")
    old_sizes = set(o.get("ground_truth") or {}) | {f"{r['size'][0]}x{r['size'][1]}" for r in o.get("rows") or []}
    for size, g in (n.get("ground_truth") or {}).items():
        if size not in old_sizes:
            checks[size] = "a size of its own (nothing to compare)"
            continue
        og = (o.get("ground_truth") or {}).get(size) or {}
        (oshots, oframes), (nshots, nframes) = _shots_of(o, size), _shots_of(n, size)
        if (oshots, oframes) != (nshots, nframes):
            problems.append(f"{size}: this run measured shots {nshots} at frames {nframes}, {where} {oshots} at {oframes} (--rooms/--frames)")
        for key in ("kind", "samples", "seed"):
            if og.get(key) != g.get(key):
                problems.append(f"{size}: ground truth {key} {g.get(key)!r}, {where} {og.get(key)!r} (--reference-samples)")
        if og.get("data_sha256") and g.get("data_sha256") and og["data_sha256"] != g["data_sha256"]:
            problems.append(f"{size}: the same shot names hold other frames (digest of the channels and rgb differs): the data set was rebuilt")
        if "reference_sha256" not in g or problems:
            continue
        if og.get("reference_sha256") == g["reference_sha256"]:
            checks[size] = "reference and data digests equal to the kept rows'" if og.get("data_sha256") == g.get("data_sha256") \
                else "reference digest equal to the kept rows'"
            continue
        new_rows = [r for r in n.get("rows") or [] if f"{r['size'][0]}x{r['size'][1]}" == size]
        if not new_rows:
            continue  # nothing measured yet at this size: checked with its first row
        nf = next((r for r in new_rows if r["method"] == tiers.FORMULA), None)
        of = next((r for r in o.get("rows") or [] if r["method"] == tiers.FORMULA and f"{r['size'][0]}x{r['size'][1]}" == size), None)
        if nf is None or of is None:
            problems.append(f"{size}: cannot check that this run's reference is the kept rows' ("
                            + ("no reference digest in " + where if not og.get("reference_sha256") else "its digest differs")
                            + "): add formula to --methods (a deterministic row to re-score)" + (f"; {where} has none" if of is None else ""))
            continue
        off = {k: (nf.get(k), of.get(k)) for k, tol in PROBE_TOLERANCE.items()
               if nf.get(k) is not None and of.get(k) is not None
               and abs(nf[k] - of[k]) > (tol * abs(of[k]) if k == "tc" else tol)}
        if off:
            problems.append(f"{size}: the formula row re-scored against this run's reference differs from the kept one ("
                            + ", ".join(f"{k} {a:.5g} vs {b:.5g}" for k, (a, b) in off.items())
                            + "): another reference or other frames")
        else:
            checks[size] = (f"formula row re-scored: PSNR {nf['psnr']:.5f} vs {of['psnr']:.5f} kept, TC {nf['tc']} vs {of['tc']}, "
                            f"PSNR vs data set {nf['psnr_dataset']:.5f} vs {of['psnr_dataset']:.5f}")
    return problems, checks


def _row_order(r: dict) -> tuple:
    kinds = [*tiers.TIERS, "cycles"]  # the tiers in cost order, then Cycles
    return (r["size"][0] * r["size"][1], kinds.index(r["kind"]) if r["kind"] in kinds else 9, r.get("scheme") == "sequential", r.get("sampler") or "",
            r.get("steps") or 0, r.get("samples") or 0)


def merge(old: dict, new: dict, section: str = "", origin: Path | None = None, merged_with: str | None = None) -> dict:
    """`old` with `new`'s rows: in section `section` ('' the main one), a row of `new` replaces the row of the same
    method and size, the others are kept; each row names its run (`runs`; `merged_with`: the command that merged a
    finished result). MergeError when `merge_problems`."""
    where = str(origin) if origin is not None else "the result merged into"
    if old.get("format") != "x2video-pareto":
        raise MergeError(f"--merge {where}: not a bench.pareto result (format {old.get('format')!r})")
    problems, checks = merge_problems(old, new, section, where)
    if problems:
        raise MergeError(f"--merge {where}{f' (section {section!r})' if section else ''}: this run does not measure what it holds:\n  - "
                         + "\n  - ".join(problems))
    out = {k: v for k, v in old.items() if k not in ("runs",)}
    runs = [dict(r) for r in old.get("runs") or []]
    if not runs:  # a result from before runs were recorded: one run made all its rows
        runs = [_run_record(old, 1, "", origin)]
        out["rows"] = [{**r, "run": 1} for r in old.get("rows") or []]
    run_id = max(r["id"] for r in runs) + 1
    rec = _run_record(new, run_id, section)
    rec["merge_checks"] = checks
    if merged_with:
        rec["merged_with"] = merged_with
    runs.append(rec)
    n = _section(new, "")
    o = _section(out, section) or {"data": n["data"], "split": n["split"], "rooms": {}, "frames": {}, "ground_truth": {}, "rows": [],
                                   "unavailable": []}
    measured = {(r["method"], tuple(r["size"])) for r in n["rows"]} | {(u["method"], tuple(u["size"])) for u in n["unavailable"]}
    rows = [r for r in o["rows"] if (r["method"], tuple(r["size"])) not in measured] + [{**r, "run": run_id} for r in n["rows"]]
    merged = {"data": o["data"], "split": o["split"], "rooms": {**o["rooms"], **n["rooms"]}, "frames": {**o["frames"], **n["frames"]},
              "ground_truth": {**o["ground_truth"], **n["ground_truth"]}, "rows": sorted(rows, key=_row_order),
              "unavailable": [u for u in o["unavailable"] if (u["method"], tuple(u["size"])) not in measured] + list(n["unavailable"])}
    merged["summary"] = summarise(merged["rows"])
    if section:
        merged["schemes"] = compare_schemes(merged["rows"])
        out["sections"] = {**(old.get("sections") or {}), section: merged}
    else:
        out.update(merged)
    for key in ("command", "date", "machine", "load_average_start", "load_average_end", "weights", "weights_sha256", "residual_net", "has_lcm",
                "wall_seconds"):
        if key in new:
            out[key] = new[key]  # the latest run's (each run's own: `runs`)
    if merged_with:
        out["command"] = merged_with  # what wrote this file
    out["summary"] = summarise(out["rows"])  # derived: recomputed for every section (the code may have changed since)
    for sec in (out.get("sections") or {}).values():
        sec["summary"], sec["schemes"] = summarise(sec["rows"]), compare_schemes(sec["rows"])
    out["complete"] = bool(old.get("complete", True)) and bool(new.get("complete", True))
    out["runs"] = runs
    return out


def compare_schemes(rows: list[dict]) -> list[dict]:
    """Per size and sampler-steps measured both ways: recursive against sequential sampling (PSNR, TC, CPU and wall seconds)."""
    out = []
    for r in rows:
        if not tiers.windowed(r["kind"]) or r.get("scheme") != "recursive":
            continue
        q = next((x for x in rows if x["method"] == r["method"] + "-seq" and x["size"] == r["size"]), None)
        if q is not None:
            out.append({"size": r["size"], "setting": r["method"], **{f"{k}_{s}": x.get(k) for s, x in (("recursive", r), ("sequential", q))
                                                                      for k in ("psnr", "tc", "cpu_seconds_per_frame", "wall_seconds_per_frame")}})
    return out


# --------------------------------------------------------------------------------------------- outputs
FAMILY_STYLE = {"formula": ("s", "black"), "residual": ("D", "tab:green"), "ddim-recursive": ("o", "tab:blue"),
                "ddim-sequential": ("o", "tab:cyan"), "lcm-recursive": ("^", "tab:orange"), "lcm-sequential": ("^", "gold"),
                "cycles": ("*", "tab:red")}


FAMILY_NAMES = {"formula": "formula (tier 0)", "residual": "tier 1 (residual net)", "ddim-recursive": "DDIM, recursive",
                "ddim-sequential": "DDIM, sequential", "lcm-recursive": "LCM, recursive", "lcm-sequential": "LCM, sequential",
                "cycles": "Cycles + OIDN"}


def _gt_line(ground_truth: dict) -> str:
    gts = {(v["kind"], str(v["samples"])) for v in ground_truth.values()}
    if len(gts) == 1 and len(ground_truth) > 1:
        v = next(iter(ground_truth.values()))
        return f"{'Cycles' if v['kind'] == 'bench reference' else 'the data set'} at {v['samples']} spp + OIDN, every size"
    return "; ".join(f"{k}: {'Cycles' if v['kind'] == 'bench reference' else 'the data set'} at {v['samples']} spp + OIDN"
                     + (" (own noise seed)" if v["kind"] == "bench reference" else "") for k, v in ground_truth.items())


def _shots_text(g: dict) -> str:
    """'room_00007, room_00015 (8 frames each)' from a section's ground-truth entry."""
    shots, frames = g.get("shots", []), g.get("frames", [])
    if len(set(frames)) == 1:
        return f"{', '.join(shots)} ({frames[0]} frames{' each' if len(shots) > 1 else ''})"
    return ", ".join(f"{s} ({n} frames)" for s, n in zip(shots, frames))


def _main_run(rows: list[dict]) -> Any:
    """The run that measured most of these rows (the others are tagged on the chart)."""
    runs = [r.get("run") for r in rows]
    return max(set(runs), key=runs.count) if runs else None


def _panels(axes: Any, rows: list[dict], clock: str | None) -> list[tuple[int, int]]:
    """PSNR and TC against seconds per frame (log) on two axes: one line per family and size (solid the smallest size,
    dashed the next), the formula a horizontal line per size; a row from another run than most is tagged [run k]."""
    sizes = sorted({tuple(r["size"]) for r in rows}, key=lambda s: s[0] * s[1])
    dashes = {s: ("-" if i == 0 else "--" if i == 1 else ":") for i, s in enumerate(sizes)}
    usual = _main_run(rows)
    for ax, key, ylabel in ((axes[0], "psnr", "PSNR (dB) ↑"), (axes[1], "tc", "TC (warping error / ground truth's) ↓")):
        for size in sizes:
            rs = [r for r in rows if tuple(r["size"]) == size and r.get(key) is not None]
            form = next((r for r in rs if r["kind"] == tiers.FORMULA), None)
            if form is not None:
                ax.axhline(form[key], color="black", lw=0.8, ls=dashes[size], alpha=0.5)
            for fam in dict.fromkeys(r["family"] for r in rs):
                pts = sorted((r for r in rs if r["family"] == fam), key=lambda r: r["seconds_per_frame"])
                marker, colour = FAMILY_STYLE.get(fam, ("x", "grey"))
                ax.plot([r["seconds_per_frame"] for r in pts], [r[key] for r in pts], ls=dashes[size], marker=marker, color=colour,
                        ms=7 if marker != "*" else 11, label=f"{FAMILY_NAMES.get(fam, fam)} {size[0]}x{size[1]}")
                for r in pts:
                    tag = r["label"].replace(" + OIDN", "").replace("tier 1 (residual net)", "tier 1").replace("formula (tier 0)", "formula")
                    tag = tag.replace(" sequential", " seq") + (f" [run {r['run']}]" if r.get("run") not in (None, usual) else "")
                    ax.annotate(tag, (r["seconds_per_frame"], r[key]), textcoords="offset points", xytext=(4, 3), fontsize=6, color=colour)
        ax.set_xscale("log")
        ax.set_xlabel(("CPU seconds per frame, all threads" if clock == "cpu" else "wall seconds per frame") + " (log) ↓")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, which="both")
    return sizes


def _runs_line(result: dict) -> str:
    runs = result.get("runs") or []
    if not runs:
        return f"load {result['load_average_start'][0]:.1f}"
    return "; ".join(f"run {r['id']} {str(r.get('date') or '?')[:10]} load {((r.get('load_average_start') or [float('nan')])[0]):.1f}: "
                     + (", ".join(r["methods"]) if len(r["methods"]) <= 4 else f"{len(r['methods'])} methods")
                     + (f" ({r['section']})" if r.get("section") else "") for r in runs)


def draw(result: dict, path: Path) -> Path:
    """Two panels, PSNR and TC against seconds per frame (log), for the main rows (`_panels`); a row of two more per
    section (`--section`: e.g. recursive against sequential sampling on a longer shot)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from x2video.eval.machine import machine_label
    from x2video.io.atomic import atomic_path

    ok = lambda rs: [r for r in rs if r.get("psnr") is not None and r["seconds_per_frame"] > 0]  # noqa: E731
    rows = ok(result["rows"])
    if not rows:
        raise ValueError("pareto chart: no row with PSNR and seconds per frame")
    sections = [(name, sec, ok(sec["rows"])) for name, sec in (result.get("sections") or {}).items() if ok(sec["rows"])]
    fig, axes = plt.subplots(1 + len(sections), 2, figsize=(12, 5 + 4.2 * len(sections)), dpi=110, squeeze=False)
    sizes = _panels(axes[0], rows, result.get("clock"))
    handles, labels = axes[0][0].get_legend_handles_labels()
    for i, (name, sec, srows) in enumerate(sections, start=1):
        _panels(axes[i], srows, result.get("clock"))
        shots = "; ".join(f"{k}: {_shots_text(g)}, ground truth "
                          f"{'Cycles' if g['kind'] == 'bench reference' else 'the data set'} at {g['samples']} spp + OIDN"
                          for k, g in sec["ground_truth"].items())
        axes[i][0].set_title(f"{name}: {shots}", fontsize=8, loc="left")
        for h, lab in zip(*axes[i][0].get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), fontsize=7, frameon=False)
    fig.suptitle(f"speed vs accuracy on path-traced test rooms ({machine_label(result['machine'])}, {result['threads']} threads; "
                 f"{_runs_line(result)})\nground truth: {_gt_line(result['ground_truth'])}\nformula: horizontal line; solid = "
                 f"{sizes[0][0]}x{sizes[0][1]}" + (f", dashed = {sizes[1][0]}x{sizes[1][1]}" if len(sizes) > 1 else ""), fontsize=8)
    top = 1 - 0.55 / fig.get_figheight()
    fig.tight_layout(rect=(0, (0.5 if len(labels) > 6 else 0.3) / fig.get_figheight(), 1, top))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


def _table(rows: list[dict], with_run: bool) -> list[str]:
    f = lambda v, d: "—" if v is None else f"{v:.{d}f}"  # noqa: E731
    lines = ["| size | setting | wall s/frame ↓ | CPU s/frame ↓ | PSNR ↑ | SSIM ↑ | TC ↓ | PSNR vs data set frames |" + (" run |" if with_run else ""),
             "|---|---|---|---|---|---|---|---|" + ("---|" if with_run else "")]
    for r in rows:
        lines.append(f"| {r['size'][0]}x{r['size'][1]} | {r['label']} | {r['wall_seconds_per_frame']:.3f} | {f(r['cpu_seconds_per_frame'], 3)} | "
                     f"{f(r['psnr'], 2)} | {f(r['ssim'], 4)} | {f(r['tc'], 3)} | {f(r['psnr_dataset'], 2)} |"
                     + (f" {r.get('run', '—')} |" if with_run else ""))
    return lines


def _unavailable(sec: dict) -> list[str]:
    if not sec.get("unavailable"):
        return []
    return ["", "Not measured: " + "; ".join(f"{u['method']} at {u['size'][0]}x{u['size'][1]} ({u['reason']})" for u in sec["unavailable"]) + "."]


def markdown(result: dict) -> str:
    runs = result.get("runs") or []
    head = (f"*Generated by `{result['command']}`; do not edit by hand.*" if not runs else
            f"*Generated by {len(runs)} runs of `python -m bench.pareto` merged with `--merge` (each row names its run); do not edit by hand.*")
    lines = ["# Speed vs accuracy (bench.pareto)", "", head, "",
             f"Machine: {result['machine'].get('cpu', '?')}, {result['threads']} threads; "
             + (f"load average {result['load_average_start'][0]:.1f} at the start, {result['load_average_end'][0]:.1f} at the end"
                if not runs else "load averages per run below")
             + " (a shared 2-core VM: seconds compare within a run; across runs only as well as the loads agree). "
             + f"Weights: {result['weights']}. Data: {', '.join(result['data'])} ({result['split']}): "
             + ", ".join(f"at {k} the first {v} room(s), first {result['frames'][k]} frames" for k, v in result["rooms"].items())
             + (f". {result['wall_seconds'] / 60:.1f} min in all." if not runs else "."), ""]
    if runs:
        lines += ["| run | date | commit | load average start → end | minutes | weights (residual.safetensors / unet.safetensors SHA-256) | "
                  "diffusion engine | rows | command |", "|---|---|---|---|---|---|---|---|---|"]
        for r in runs:
            w = r.get("weights_sha256") or {}
            la, lb = (r.get("load_average_start") or ["?"])[0], (r.get("load_average_end") or ["?"])[0]
            lines.append(f"| {r['id']} | {r.get('date') or '?'}{' (' + r['date_note'] + ')' if r.get('date_note') else ''} | "
                         f"{str(r.get('commit') or '?')[:10]} | {la} → {lb} | {(r.get('wall_seconds') or 0) / 60:.1f} | "
                         f"{w.get('residual.safetensors', 'not recorded')} / {w.get('unet.safetensors', 'not recorded')} | "
                         f"{', '.join(r.get('engines') or []) or 'not recorded'} | "
                         f"{', '.join(r['methods'])}{' (section ' + r['section'] + ')' if r.get('section') else ''} | `{r.get('command')}`"
                         + (f", merged by `{r['merged_with']}`" if r.get("merged_with") else "") + " |")
        checks = [f"run {r['id']} at {k}: {v}" for r in runs for k, v in (r.get("merge_checks") or {}).items()]
        if checks:
            lines += ["", "Merge checks (same shots, frames and ground truth as the rows kept): " + "; ".join(checks) + "."]
        lines.append("")
    for size, g in result["ground_truth"].items():
        lines.append(f"Ground truth at {size}: {g['note']}.")
    lines += ["", f"The chart's x and 'fastest' below use the {result['clock']} seconds.", ""]
    lines += _table(result["rows"], bool(runs)) + _unavailable(result)
    lines += ["", "## The shipped model's fastest setting within 0.5 dB of its best", ""]
    sp = lambda v: "—" if v is None else f"{v:.1f}×"  # noqa: E731
    for size, s in result["summary"].items():
        lines.append(f"- {size}: best PSNR {s['best_psnr']:.2f} dB ({s['best']}); fastest within {s['near_best_db']} dB: **{s['fastest_near_best']}**"
                     f" ({s['fastest_psnr']:.2f} dB, {s['fastest_cpu_seconds_per_frame']:.3f} CPU s/frame, {s['fastest_wall_seconds_per_frame']:.3f} "
                     f"wall s/frame): {sp(s['speedup_over_ddim20_cpu'])} faster than DDIM-20 and {sp(s['speedup_over_cycles64_cpu'])} faster "
                     f"than Cycles at 64 samples in CPU time ({sp(s['speedup_over_ddim20_wall'])} and {sp(s['speedup_over_cycles64_wall'])} "
                     "in wall time)"
                     + (f"; Cycles at 64 samples scores {s['cycles64_psnr']:.2f} dB" if s.get("cycles64_psnr") is not None else "")
                     + (f" (timed in runs {s['runs']['fastest']}, {s['runs']['ddim20']} and {s['runs']['cycles64']} respectively: "
                        "seconds of different runs compare only as well as their loads do)"
                        if len({v for v in (s.get("runs") or {}).values() if v is not None}) > 1 else "") + ".")
    for name, sec in (result.get("sections") or {}).items():
        lines += ["", f"## {name}", "", f"Data: {', '.join(sec['data'])} ({sec['split']})."]
        for size, g in sec["ground_truth"].items():
            lines.append(f"At {size}: {_shots_text(g)}; ground truth: {g['note']}.")
        lines += [""] + _table(sec["rows"], bool(runs)) + _unavailable(sec)
        if sec.get("schemes"):
            f = lambda v, d: "—" if v is None else f"{v:.{d}f}"  # noqa: E731
            lines += ["", "Recursive against sequential sampling:", "",
                      "| size | setting | PSNR recursive / sequential | TC recursive / sequential | CPU s/frame recursive / sequential |",
                      "|---|---|---|---|---|"]
            for c in sec["schemes"]:
                lines.append(f"| {c['size'][0]}x{c['size'][1]} | {c['setting']} | {f(c['psnr_recursive'], 2)} / {f(c['psnr_sequential'], 2)} | "
                             f"{f(c['tc_recursive'], 3)} / {f(c['tc_sequential'], 3)} | {f(c['cpu_seconds_per_frame_recursive'], 3)} / "
                             f"{f(c['cpu_seconds_per_frame_sequential'], 3)} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_fields(ap, ParetoOptions)
    opts = from_args(ParetoOptions, ap.parse_args(argv))
    from x2video.io.atomic import write_json_atomic, write_text_atomic

    if opts.replot:
        src = Path(opts.replot)
        result = json.loads(src.read_text())
        md = results_path("pareto", src.stem, ".md") if not opts.out else Path(opts.out).with_suffix(".md")
        write_text_atomic(md, markdown(result))
        print(f"wrote {md}, {draw(result, (Path(opts.out) if opts.out else src).with_suffix('.png')) if opts.png else ''}")
        return 0

    if (opts.section or opts.from_result) and not opts.merge:
        raise SystemExit("--section and --from-result go with --merge (the result to add to)")
    if opts.merge:
        origin = Path(opts.merge)
        if not origin.is_file():
            raise SystemExit(f"--merge {origin}: no such file")
        old = json.loads(origin.read_text())
        out = Path(opts.out) if opts.out else origin
        if opts.from_result:
            result = clean_json(merge(old, json.loads(Path(opts.from_result).read_text()), opts.section, origin, command("pareto", argv)))
        else:
            if _section(old, opts.section) is not None:
                keys = [t.strip().lower() for t in opts.methods.split(",") if t.strip()]
                opts = dataclasses.replace(opts, methods=",".join([tiers.FORMULA] + [k for k in keys if k != tiers.FORMULA]))
                print("--merge: formula is measured first (a deterministic row: it checks this run's reference against the kept rows')",
                      file=sys.stderr)
            result = clean_json(merge(old, clean_json(measure(opts, argv, lambda partial: write_json_atomic(
                out, clean_json(merge(old, clean_json(partial), opts.section, origin))))), opts.section, origin))
    else:
        out = Path(opts.out) if opts.out else DOCS / "pareto.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        result = clean_json(measure(opts, argv, lambda partial: write_json_atomic(out, clean_json(partial))))
    write_json_atomic(out, result)
    md = results_path("pareto", out.stem, ".md") if out.resolve().parent == DOCS.resolve() else out.with_suffix(".md")
    md.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(md, markdown(result))
    wrote = [out, md]
    if opts.png:
        try:
            wrote.append(draw(result, out.with_suffix(".png")))
        except ImportError:
            print("no PNG: matplotlib is not installed (pip install 'x2video-studio[bench]')", file=sys.stderr)
    for size, s in result["summary"].items():
        print(f"{size}: fastest within {NEAR_BEST_DB} dB of the best ({s['best']}, {s['best_psnr']:.2f} dB): {s['fastest_near_best']} "
              f"{s['fastest_cpu_seconds_per_frame']:.3f} CPU s/frame; CPU-time speed-up x{s['speedup_over_ddim20_cpu'] or float('nan'):.1f} "
              f"over DDIM-20, x{s['speedup_over_cycles64_cpu'] or float('nan'):.1f} over Cycles-64 "
              f"(wall x{s['speedup_over_ddim20_wall'] or float('nan'):.1f}, x{s['speedup_over_cycles64_wall'] or float('nan'):.1f})")
    for name, sec in (result.get("sections") or {}).items():
        for c in sec.get("schemes") or []:
            print(f"{name}, {c['size'][0]}x{c['size'][1]} {c['setting']}: recursive PSNR {c['psnr_recursive']:.2f} TC {c['tc_recursive']} "
                  f"{c['cpu_seconds_per_frame_recursive']:.3f} CPU s/frame; sequential PSNR {c['psnr_sequential']:.2f} TC {c['tc_sequential']} "
                  f"{c['cpu_seconds_per_frame_sequential']:.3f} CPU s/frame")
    print("wrote " + ", ".join(str(p) for p in wrote))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
