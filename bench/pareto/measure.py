"""The bench itself: what `python -m bench.pareto` measures (ParetoOptions), every row timed and scored per size, and
the summary of the fastest setting near the best."""
from __future__ import annotations

import datetime
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bench.common import command
from bench.pareto.data import bpy_available, cycles_job, frames_sha256, images_sha256, parse_sizes, per_size, run_cycles, shots_by_size
from bench.pareto.methods import METHODS, diffusion_settings, parse_method, same_plan, warm_up
from bench.ptscore import display, render_timed, score, truth, truth_label

#: within this many dB of the best PSNR counts as "as good" for the summary's fastest setting
NEAR_BEST_DB = 0.5


@dataclass
class ParetoOptions:
    """What `python -m bench.pareto` measures (flags via `x2video.fields`)."""

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


def measure(opts: ParetoOptions, argv: list[str] | None, on_partial: Any = None) -> dict:
    """The result (see the module docstring); `on_partial(result)` after each row, with "complete": False."""
    import torch

    from x2video.io import load_shot
    from x2video.render.renderer import Renderer

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
                                              f"({'/'.join(map(str, samples_gt)) or '?'} spp, denoised; truth: {truth_label(shots)})"
                                              " give psnr_dataset"}
        else:
            why = "--reference-samples 0" if not opts.reference_samples else f"no bench reference: {why_no_cycles}"
            apart = truth_label(shots)
            if apart.startswith("apart, "):  # every shot has its truth apart (`x2video dataset truth`): that is the reference
                recs = [ground_truth(s).record or {} for s in shots]
                samples_t, seeds = sorted({r["samples"] for r in recs}), sorted({r["seed"] for r in recs})
                ground_truth[size_key] = {"kind": "data set truth apart", "samples": samples_t, "denoise": "OpenImageDenoise",
                                          "seed": seeds[0] if len(seeds) == 1 else seeds,
                                          "note": f"the data set's truth apart ({apart}, denoised; the passes at "
                                                  f"{'/'.join(map(str, samples_gt)) or '?'} spp, seed 0) ({why})"}
            else:
                ground_truth[size_key] = {"kind": "data set frames", "samples": samples_gt, "denoise": "OpenImageDenoise",
                                          "note": f"the data set's frames at {'/'.join(map(str, samples_gt)) or '?'} spp, denoised ({why};"
                                                  f" truth: {apart})"
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
