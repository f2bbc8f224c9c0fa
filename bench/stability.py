"""Stability where methods fail: every tier on the inputs that break renderers, with what happens (issue 30 item 3).

Each cell renders one case with one method and records PSNR (display images, `x2video.channels.tonemap`, in
the shot's own units: frames divided by `shot.info.irradiance_scale`), TC (DIS flow on the ground truth),
seconds, peak RSS (the process's high-water mark, reset before the cell through /proc/self/clear_refs),
the share of non-finite output values and whether it crashed (the exception's message). Methods:

    formula    tier 0, albedo x irradiance (RenderSettings.quality 'formula')
    residual   tier 1 forced (quality 'residual'): one pass of the tier-1 net over the formula
    auto       what the product picks (tier 1 where nothing must be generated and the net's record trusts it,
               else the formula; the sampler where something must be generated), preset fast
    diffusion  the video diffusion sampler, preset fast (LCM-2 with the shipped weights)

Families (the grid; `--quick` runs a few cells of each at small sizes and short shots):

    channels  the 32 subsets of the five channels kept (the rest dropped via Edits.dropped)
    masks     0-16 masks from the ids channel (rectangles without one), MaskOut A|M|R in each, with and
              without local prompts (the object's caption); PSNR inside / outside the masks
    length    1 .. 1,000 frames of a lazily looped shot (ping-pong over the source's frames, never in
              memory): mean CIE76 Lab dE to the ground truth along the shot (drift) and memory
    size      8x8 .. 1920x1080, sizes not divisible by 8 (the source resized on the fly)
    noise     the irradiance as Cycles sampled it (NoisyDiffDir + NoisyDiffInd, before denoising), and
              Poisson-like noise emulating 1 .. 128 samples per pixel
    hostile   NaN, +-Inf and 1e6 irradiance in a patch, negative roughness, zero normals, albedo 0 or 1
    limits    the paper's limitation cases per pixel class: window (normal == 0), metal (metallic > 0.5),
              mirror (metallic > 0.5 and roughness < 0.05), other
    foreign   the source rewritten as other tools write shots and read back by our loaders (bench/stability_foreign.py):
              8-bit PNGs in the XRGB release's layout, irradiance in another scale and in sRGB, 1024x1024 and
              1920x1080, an emissive fixture, V-RGBX videos; scored after one fitted exposure per frame. Auto must
              stay within AUTO_BELOW_DB of the formula on every case (issue 49)

Source data: `--data`, a folder of path-traced shots with rgb ground truth (Cycles multi-layer EXRs, e.g.
DATA/test); without it a small synthetic shot (numpy, no renderer) stands in and the results say so. A source with
a truth apart (``truth/``, `x2video dataset truth`) is scored against it; the result's "truth" says which.
The diffusion tier is skipped (recorded as skipped, with why) above `--diffusion-max-pixels` and
`--diffusion-max-frames`: on a 2-core CPU a 1,000-frame diffusion render takes hours. Large frames run at the
diffusion tier's working size (`RenderSettings.working_pixels`): the foreign family's 1920x1080 cell, 8 frames,
takes about 8 s, so the pixel cap only keeps out frames larger than that.

    python -m bench.stability [--quick] [--data DATA/test] [--families channels,masks,...] [--methods formula,residual,auto,diffusion]

Writes bench/results/stability/stability[_quick].json and docs/STABILITY.md with its plots (docs/stability/).
This file holds the grid, the findings and the command; one cell is bench/stability_cells.py, the shots and
the case transforms bench/stability_shots.py, the report bench/stability_report.py.
"""
from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

from bench.stability_cells import TC_FRAMES, Context, run_cell
from bench.stability_shots import HOSTILE, SyntheticShot, cycles_noise
from x2video.channels import INTRINSIC
from x2video.shot import Shot

FAMILIES = ("channels", "masks", "length", "noise", "hostile", "limits", "size", "foreign")  # size late: its big frames raise the RSS floor
METHODS = ("formula", "residual", "auto", "diffusion")
#: a method counts as "far below the formula" this many dB under it
FAR_BELOW_DB = 3.0
#: auto's promise on the foreign family: never more than this under the formula
AUTO_BELOW_DB = 0.2
DOCS = Path(__file__).resolve().parents[1] / "docs"


# --------------------------------------------------------------------------------------------- the grid
ALL_SUBSETS = [tuple(c for c, keep in zip(INTRINSIC, bits) if keep) for bits in itertools.product((1, 0), repeat=5)]


def subset_name(kept: tuple[str, ...]) -> str:
    return "+".join(c[:3] for c in kept) if kept else "none"


def grid(quick: bool, n_sources: int, has_cycles: bool, families: tuple[str, ...], methods: tuple[str, ...]) -> list[dict]:
    """The cells: (family, name, method, params) for each family and method."""
    cases: list[tuple[str, str, dict]] = []
    if quick:
        subsets = [s for s in ALL_SUBSETS if len(s) in (0, 5) or s in (("albedo", "irradiance"), ("albedo", "normal", "roughness", "metallic"),
                                                                        ("normal", "roughness", "metallic", "irradiance"))]
        masks = [(0, False), (1, False), (1, True), (16, False), (16, True)]
        lengths = [1, 2, 17, 65]
        sizes = [(8, 8), (13, 11), (64, 64), (100, 75), (333, 217), (1920, 1080)]
        spps = [1, 16, 128]
        hostile = list(HOSTILE)
        limits = [(i, 3) for i in sorted({0, n_sources - 1})]  # first and last shot (pt160: a mirror room, a window room)
    else:
        subsets = ALL_SUBSETS
        masks = [(n, lp) for n in (0, 1, 2, 4, 8, 16) for lp in (False, True) if n or not lp]
        lengths = [1, 2, 17, 65, 257, 1000]
        sizes = [(8, 8), (9, 7), (13, 11), (16, 16), (31, 17), (64, 64), (100, 75), (160, 112), (333, 217), (640, 360), (1001, 563),
                 (1280, 720), (1920, 1080)]
        spps = [1, 2, 4, 8, 16, 32, 64, 128]
        hostile = list(HOSTILE)
        limits = [(i, 8) for i in range(n_sources)]
    if "channels" in families:
        cases += [("channels", subset_name(s), {"kept": list(s), "frames": 2}) for s in subsets]
    if "masks" in families:
        cases += [("masks", f"{n}{'+prompts' if lp else ''}", {"masks": n, "local_prompts": lp, "frames": 2}) for n, lp in masks]
    if "length" in families:
        cases += [("length", f"{n}f", {"frames": n}) for n in lengths]
    if "size" in families:
        cases += [("size", f"{w}x{h}", {"size": [w, h], "frames": 2}) for w, h in sizes]
    if "noise" in families:
        if has_cycles:
            cases.append(("noise", "cycles_noisy", {"noise": "cycles", "frames": 2 if quick else 8}))
        cases += [("noise", f"{s}spp", {"noise": "poisson", "spp": s, "frames": 2}) for s in spps]
    if "hostile" in families:
        cases += [("hostile", h, {"case": h, "frames": 2}) for h in hostile]
    if "limits" in families:
        cases += [("limits", f"shot{i}", {"source": i, "frames": n}) for i, n in limits]
    if "foreign" in families:
        from bench.stability_foreign import CASES, QUICK

        cases += [("foreign", n, {"case": n, "frames": 2, **({"size": list(CASES[n].size)} if CASES[n].size else {})})
                  for n in (QUICK if quick else CASES)]
    cases.sort(key=lambda c: FAMILIES.index(c[0]))  # stable: FAMILIES' order, size last
    return [{"family": f, "name": n, "method": m, "params": p} for f, n, p in cases for m in methods]


# --------------------------------------------------------------------------------------------- findings
def findings(cells: list[dict]) -> list[dict]:
    """Failures: a crash, non-finite output, or a PSNR more than FAR_BELOW_DB under the formula's on the same case
    (auto on the foreign family: more than AUTO_BELOW_DB)."""
    from x2video.tiers.registry import FORMULA

    formula = {(c["family"], c["name"]): c for c in cells if c["method"] == FORMULA}
    out = []
    for c in cells:
        if c.get("skipped"):
            continue
        kind = None
        if c["crashed"]:
            kind = "crash"
        elif c.get("nonfinite_frac", 0) > 0:
            kind = "non-finite output"
        elif c.get("mean_display") == 0.0:
            kind = "black frames"
        elif c["method"] != FORMULA:
            f = formula.get((c["family"], c["name"]))
            below = FAR_BELOW_DB if c["family"] != "foreign" or c["method"] != "auto" else AUTO_BELOW_DB
            if f and not f["crashed"] and c.get("psnr") is not None and f.get("psnr") is not None and c["psnr"] < f["psnr"] - below:
                kind = f"{f['psnr'] - c['psnr']:.{1 if below >= 1 else 2}f} dB below the formula"
        if kind:
            out.append({"family": c["family"], "name": c["name"], "method": c["method"], "failure": kind, "error": c.get("error"),
                        "tier": c.get("tier")})
    return out


# --------------------------------------------------------------------------------------------- report
def merge_results(outs: list[dict]) -> dict:
    """One result from several runs: the first's header, but the model record of the last run that has one (the cells
    of the tiers it loads replace the earlier runs') and the longest list of source shots; every run's cells (a later
    run's cell replaces an earlier one of the same family, case and method, in place), the commands joined, findings
    recomputed."""
    merged = dict(outs[0])
    models = [o["model"] for o in outs if o.get("model")]
    if models:
        merged["model"] = models[-1]
    if any("sources" in o for o in outs):
        merged["sources"] = max((o.get("sources", []) for o in outs), key=len)
    cells: dict[tuple[str, str, str], dict] = {}
    for i, o in enumerate(outs):
        for c in o["cells"]:
            cells[(c["family"], c["name"], c["method"])] = {**c, "run": i}  # which run it comes from (the report says)
    merged["cells"] = list(cells.values())
    datas = list(dict.fromkeys(o["data"] for o in outs if o.get("data")))  # every run's data, in order (each run's command names its own)
    if datas:
        merged["data"] = " and ".join(datas)
    merged["command"] = " ; ".join(o["command"] for o in outs)
    merged["wall_seconds"] = sum(o.get("wall_seconds", 0.0) for o in outs)
    merged["findings"] = findings(merged["cells"])
    return merged


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a reduced grid (a few cells per family, small sizes, short shots)")
    ap.add_argument("--data", type=Path, default=None, help="folder of path-traced shots with rgb ground truth (default: a synthetic shot)")
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--weights", default=None, help="model folder (default: the shipped weights)")
    ap.add_argument("--residual", default=None, help="folder with residual.safetensors (default: the model's, else random init)")
    ap.add_argument("--diffusion-max-pixels", type=int, default=1920 * 1080)
    ap.add_argument("--diffusion-max-frames", type=int, default=None, help="default 65, 17 with --quick")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--name", default=None, help="results name (default stability, or stability_quick with --quick)")
    ap.add_argument("--no-docs", action="store_true", help="do not write docs/STABILITY.md")
    ap.add_argument("--report", type=Path, nargs="+", default=None,
                    help="only write docs/STABILITY.md from these results JSONs (a later file's cells replace an earlier's)")
    args = ap.parse_args(argv)
    if args.report is not None:
        from bench.stability_report import write_report

        write_report(merge_results([json.loads(p.read_text()) for p in args.report]), DOCS / "STABILITY.md", DOCS / "stability")
        return 0
    import torch

    from bench.common import clean_json, command, results_path
    from x2video.eval.machine import machine_info
    from x2video.io.atomic import write_json_atomic
    from x2video.io.paths import portable_path

    torch.set_num_threads(args.threads)
    sources: list[Shot] = []
    if args.data is not None:
        from x2video.io import load_shot

        for d in sorted(p for p in args.data.iterdir() if (p / "shot.json").is_file()):
            sh = load_shot(d)
            if sh.has("rgb") and all(sh.has(c) for c in INTRINSIC):
                sources.append(sh)
        if not sources:
            raise SystemExit(f"{args.data}: no shot with rgb and the five channels")
    else:
        sources = [SyntheticShot(8, (112, 160))]
    has_cycles = cycles_noise(sources[0]) is not None
    from x2video.io.truth import ground_truth
    from x2video.io.truth import summary as truth_summary

    truths = [ground_truth(s) for s in sources]  # truth/ (rendered apart from the passes) where a source has it, else its rgb
    ctx = Context(sources, truths=truths, weights=args.weights, residual=args.residual, diffusion_max_pixels=args.diffusion_max_pixels,
                  diffusion_max_frames=args.diffusion_max_frames or (17 if args.quick else 65), threads=args.threads)
    families = tuple(f for f in args.families.split(",") if f)
    methods = tuple(m for m in args.methods.split(",") if m)
    cells = grid(args.quick, len(sources), has_cycles, families, methods)
    name = args.name or ("stability_quick" if args.quick else "stability")
    dest = results_path("stability", name)
    dest.parent.mkdir(parents=True, exist_ok=True)
    print(f"{len(cells)} cells; sources: {len(sources)} shot(s); results -> {portable_path(dest)}", flush=True)
    results: list[dict] = []
    t_all = time.perf_counter()

    def write() -> dict:
        out = {"format": "x2video-stability", "command": command("stability", argv), "quick": args.quick,
               "data": portable_path(args.data) if args.data else "synthetic (no --data)",
               "sources": [Path(str(s.info.source)).name for s in sources], "truth": truth_summary(t.label for t in truths),
               "threads": args.threads,
               "model": ctx.model_info, "machine": machine_info(ctx._model.device if ctx._model is not None else "cpu"),
               "note": "PSNR on tonemap (clip, sRGB) in the shot's units; TC = warping error / ground truth's (DIS flow, first "
                       f"{TC_FRAMES} frames); seconds exclude scoring and model loading; peak_rss_mb = the process's VmHWM reset "
                       "before each cell (includes the loaded model); delta_e = mean CIE76 Lab dE to the ground truth",
               "wall_seconds": time.perf_counter() - t_all, "cells": results, "findings": findings(results)}
        write_json_atomic(dest, clean_json(out, 4))
        return out

    for i, cell in enumerate(cells):
        rec = run_cell(cell, ctx)
        results.append(rec)
        status = "SKIP" if rec.get("skipped") else ("CRASH " + str(rec["error"]) if rec["crashed"] else "ok")
        print(f"[{i + 1}/{len(cells)}] {rec['family']:8s} {rec['name']:22s} {rec['method']:9s} psnr {rec.get('psnr', float('nan')):6.2f} "
              f"tc {rec.get('tc') if rec.get('tc') is None else round(rec['tc'], 3)} s {rec.get('seconds', 0):7.2f} "
              f"rss {rec.get('peak_rss_mb', 0):7.0f}MB tier {rec.get('tier', '-')} {status}", flush=True)
        if i % 5 == 4:
            write()
    out = write()
    print(f"wrote {portable_path(dest)}; {sum(c['crashed'] for c in results)} crash(es), {len(out['findings'])} finding(s)")
    if not args.no_docs:
        from bench.stability_report import write_report

        write_report(clean_json(out, 4), DOCS / "STABILITY.md", DOCS / "stability")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
