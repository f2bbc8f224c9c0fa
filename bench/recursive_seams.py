"""Where temporal consistency is lost, recursive vs sequential sampling: TC of frame pairs produced by one window
against pairs whose frames come from different windows (a seam), by the level of the higher window.

Table (c) of `x2video eval` gives one TC per row. This renders held-out long shots with both schemes and
splits each shot's flow-warping errors by frame pair: "same window" when one sampler call produced both
frames, else "seam, level k" with k the higher level of the two windows that produced them (Recursive
Sampling's keyframes come from the top level; sequential windows are all level 1). TC of a class =
mean warping error of the prediction / that of the ground truth over the class's pairs (exact motion, as
the eval's TC).

    python -m bench.recursive_seams --data DATA [--weights RUN_OR_DIR] [--rooms 2] [--frames 65]
        [--condition drop_irradiance+ref] [--threads 1] [--out bench/results/recursive_seams/recursive_seams.json]

Each seam is also classed by its side of the window boundary (`pair_sides`): "start" when the window
that made the later frame read the earlier one (every sequential seam), "end" when the window that
made the earlier frame read the later one (the frame before an interpolation window's end reference).

Writes {"format": "x2video-recursive-seams", "command", "machine", "weights", "data", "condition",
"schemes": {scheme: {"tc", "psnr", "classes": {class: {"tc", "pairs", "brightness_jump"}},
"frame_offsets": {"level k": {"mean_abs", "per_shot"}}, "sides": {side: {"tc", "pairs"}},
"shots": {name: {class: {"tc", "pairs"}}}}}}.

A seam's TC can come from a global disagreement of the two windows: `brightness_jump` is, per pair class,
the mean |change of the prediction's mean brightness - the ground truth's| (tone-mapped units), and
`frame_offsets` the prediction's mean brightness minus the ground truth's per frame, by the level of the
window that made it (where the lighting must be inferred, each level infers its own).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bench.common import add_render_arguments, load_models, result_header, results_path, run_measure
from bench.common import settings as common_settings

RESULTS = results_path("recursive_seams")
SCHEMES = ("sequential", "recursive")


def _made_by(windows: list) -> dict:
    """frame -> the window that made it last (the seam pass makes some frames twice)."""
    return {f: w for w in windows for f in w.generate}


def pair_classes(windows: list, num_frames: int) -> list[str]:
    """For each pair (t, t+1): "same window" or "seam, level k" from the plan's windows."""
    made_by = _made_by(windows)
    return ["same window" if made_by[t] is made_by[t + 1] else f"seam, level {max(made_by[t].level, made_by[t + 1].level)}"
            for t in range(num_frames - 1)]


def pair_sides(windows: list, num_frames: int) -> list[str]:
    """For each pair (t, t+1): "same window", or at a seam the side of the window boundary it lies on:
    "start" when the window that made t+1 read t (the frame after a window's first reference: every
    sequential seam), "end" when the window that made t read t+1 (the frame before an interpolation
    window's end reference), else "other"."""
    made_by = _made_by(windows)
    out = []
    for t in range(num_frames - 1):
        wa, wb = made_by[t], made_by[t + 1]
        if wa is wb:
            out.append("same window")
        elif t in wb.refs:
            out.append("start")
        elif t + 1 in wa.refs:
            out.append("end")
        else:
            out.append("other")
    return out


def frame_levels(windows: list, num_frames: int) -> list[str]:
    """For each frame: "level k", the level of the window that made it last (keyframes: the top level)."""
    made_by = _made_by(windows)
    return [f"level {made_by[t].level}" for t in range(num_frames)]


def brightness_jumps(pred: list[np.ndarray], gt: list[np.ndarray]) -> np.ndarray:
    """(T-1,) per pair (t, t+1): |change of the prediction's mean brightness - that of the ground truth|,
    the part of a seam a global (DC) disagreement between two windows makes, in tone-mapped units."""
    mp = np.array([float(f.mean()) for f in pred])
    mg = np.array([float(f.mean()) for f in gt])
    return np.abs(np.diff(mp) - np.diff(mg))


def _tc(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> dict:
    ok = mask & np.isfinite(pred) & np.isfinite(gt)
    return {"tc": float(pred[ok].mean() / gt[ok].mean()) if ok.any() else None, "pairs": int(ok.sum())}


def measure(args: argparse.Namespace) -> dict:
    from x2video.channels import tonemap
    from x2video.conditioning.edited import resolve_reference
    from x2video.eval.conditions import build_edits, parse_condition
    from x2video.eval.data import load_eval_shots
    from x2video.eval.runner import render_shot
    from x2video.metrics.image import psnr
    from x2video.metrics.temporal import ground_truth_flows, warping_errors
    from x2video.render.renderer import Renderer

    condition = parse_condition(args.condition)
    models, _, size, _ = load_models(args)
    shots = load_eval_shots(args.data, args.split, args.rooms, args.frames, size)
    renderer = Renderer(models.video)
    per: dict[str, dict] = {s: {"pred": [], "gt": [], "classes": [], "sides": [], "shots": {}, "psnr": [],
                                        "jumps": [], "levels": [], "offsets": []} for s in args.schemes}
    for shot in shots:
        edits, _ = build_edits(shot.shot, shot.name, condition, args.seed)
        gt = [tonemap(g) for g in shot.gt]
        flows, _ = ground_truth_flows(gt, shot.motion)
        gt_err = warping_errors(gt, flows).errors
        ref = resolve_reference(shot.shot, edits) if edits is not None else None  # where the Renderer anchors the plan
        for scheme in args.schemes:
            settings = common_settings(args, sampler="ddim", steps=args.steps, scheme=scheme)
            windows = renderer.plan(shot.shot, settings, None if ref is None else ref[0])
            classes = np.array(pair_classes(windows, shot.num_frames))
            sides = np.array(pair_sides(windows, shot.num_frames))
            frames, _ = render_shot(renderer, shot, edits, settings)
            shown = [tonemap(f) for f in frames]
            err = warping_errors(shown, flows).errors
            p = per[scheme]
            p["psnr"].extend(psnr(a, b) for a, b in zip(shown, gt))
            p["jumps"].append(brightness_jumps(shown, gt))
            p["levels"].append(np.array(frame_levels(windows, shot.num_frames)))
            p["offsets"].append(np.array([float((a - b).mean()) for a, b in zip(shown, gt)]))
            p["pred"].append(err)
            p["gt"].append(gt_err)
            p["classes"].append(classes)
            p["sides"].append(sides)
            p["shots"][shot.name] = {c: _tc(err, gt_err, classes == c) for c in sorted(set(classes))}
            print(f"{shot.name} {scheme}: " + ", ".join(f"{c} TC {v['tc']:.2f} ({v['pairs']})" for c, v in p["shots"][shot.name].items()), file=sys.stderr)
    schemes = {}
    for scheme, p in per.items():
        pred, gt, classes, sides, jumps = (np.concatenate(p[k]) for k in ("pred", "gt", "classes", "sides", "jumps"))
        # per frame, by the level of the window that made it: the mean brightness offset from the ground
        # truth, shot by shot (its sign differs between shots) and its mean magnitude
        levels = sorted(set(np.concatenate(p["levels"])))
        offsets = {lv: {"mean_abs": float(np.mean(np.concatenate([np.abs(o[lvs == lv]) for o, lvs in zip(p["offsets"], p["levels"])]))),
                        "per_shot": [float(o[lvs == lv].mean()) if (lvs == lv).any() else None for o, lvs in zip(p["offsets"], p["levels"])]}
                   for lv in levels}
        schemes[scheme] = {"tc": _tc(pred, gt, np.ones_like(pred, bool))["tc"], "psnr": float(np.mean(p["psnr"])),
                           "classes": {c: {**_tc(pred, gt, classes == c), "brightness_jump": float(jumps[classes == c].mean())}
                                       for c in sorted(set(classes))},
                           "frame_offsets": offsets,
                           "sides": {c: _tc(pred, gt, sides == c) for c in sorted(set(sides))},
                           "shots": p["shots"]}
    return {
        **result_header("recursive-seams", "recursive_seams", args, models, shots, size),
        "condition": condition.to_dict(),
        "schemes": schemes,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_render_arguments(p)
    p.set_defaults(frames=65)
    p.add_argument("--condition", default="drop_irradiance+ref", help="KIND[+text][+ref] as in x2video eval --long-conditions")
    p.add_argument("--steps", type=int, default=20, help="DDIM steps (default 20)")
    p.add_argument("--schemes", type=lambda v: tuple(v.split(",")), default=SCHEMES,
                   help="comma-separated subset of sequential,recursive (default both; sequential ignores the recursive-only options)")
    p.add_argument("--out", type=Path, default=RESULTS, help=f"JSON path (default {RESULTS})")
    args = p.parse_args(argv)
    if not args.schemes or set(args.schemes) - set(SCHEMES):
        p.error(f"--schemes: a comma-separated subset of {','.join(SCHEMES)}, got {','.join(args.schemes)}")
    result = run_measure(args, measure)
    for scheme, r in result["schemes"].items():
        classes = "; ".join(f"{c} {v['tc']:.3f} ({v['pairs']} pairs)" for c, v in r["classes"].items())
        print(f"{scheme:>10}: PSNR {r['psnr']:.3f} dB, TC {r['tc']:.3f}; {classes}")
        print(" " * 12 + "brightness jump not in the ground truth: " + "; ".join(f"{c} {v['brightness_jump']:.4f}" for c, v in r["classes"].items()))
        print(" " * 12 + "frame offset from the ground truth, by the level that made it: "
              + "; ".join(f"{lv} |{v['mean_abs']:.4f}| (" + ", ".join(f"{x:+.4f}" for x in v["per_shot"] if x is not None) + ")"
                          for lv, v in r["frame_offsets"].items()))
        print(" " * 12 + "by side of the seam: " + "; ".join(f"{c} {v['tc']:.3f} ({v['pairs']} pairs)" for c, v in r["sides"].items()))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
