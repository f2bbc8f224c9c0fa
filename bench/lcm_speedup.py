"""LCM-2 vs DDIM-20 speed-up measured side by side (issue 5, table (d)): the same held-out shots rendered with
both samplers, with and without the reference frame, in alternating order, several times in one run.

`x2video eval --tables d` times each row once, one row after the other, so machine noise (10-20 % on a
shared VM) lands in the ratio. Here every repeat renders DDIM-20 and LCM-2 back to back (which goes first
alternates between repeats), and the speed-up is reported per repeat and as the median over repeats, with
the channel encoding (done once per shot; the editor caches it) both inside and outside the time.

    python -m bench.lcm_speedup --data DATA [--weights RUN_OR_DIR] [--lcm-weights LCM_RUN] [--rooms 2]
        [--frames 17] [--repeats 3] [--threads 1] [--out bench/results/lcm_speedup/lcm_speedup.json]

Writes {"format": "x2video-lcm-speedup", "command", "machine", "weights", "data", "load_average_before_after",
"repeats": [{"order", "rows": [{"name", "sampler", "steps", "reference", "seconds_per_frame",
"encode_seconds_per_frame"}], "speedup", "speedup_ref", "speedup_no_encoding", "speedup_ref_no_encoding"}],
"median": {...the four speed-ups...}, "min": {...}, "max": {...}}. No row holds a PSNR, so the editor's
speed/accuracy chart (which plots rows with both) skips this file; accuracy is table (d)'s job.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
from pathlib import Path

from bench.common import add_render_arguments, load_models, result_header, results_path, run_measure

RESULTS = results_path("lcm_speedup")
RATIOS = ("speedup", "speedup_ref", "speedup_no_encoding", "speedup_ref_no_encoding")


def _ratios(rows: list[dict]) -> dict[str, float]:
    by = {(r["sampler"], r["reference"]): r for r in rows}
    out = {}
    for name in RATIOS:
        ref = "_ref" in name
        d, lcm = by[("ddim", ref)], by[("lcm", ref)]
        if name.endswith("no_encoding"):
            out[name] = (d["seconds_per_frame"] - d["encode_seconds_per_frame"]) / (lcm["seconds_per_frame"] - lcm["encode_seconds_per_frame"])
        else:
            out[name] = d["seconds_per_frame"] / lcm["seconds_per_frame"]
    return out


def measure(args: argparse.Namespace) -> dict:
    from x2video.eval.data import load_eval_shots
    from x2video.eval.runner import MISSING_LCM
    from x2video.render.renderer import Renderer

    models, _, size, _ = load_models(args)
    if models.lcm is None:
        raise SystemExit(f"lcm_speedup: {MISSING_LCM}")
    shots = load_eval_shots(args.data, args.split, args.rooms, args.frames, size)
    return {
        **result_header("lcm-speedup", "lcm_speedup", args, models, shots, size),
        **back_to_back({"ddim": Renderer(models.video), "lcm": Renderer(models.lcm)}, shots, args),
    }


def back_to_back(renderers: dict, shots: list, args: argparse.Namespace) -> dict:
    """The timed part: `args.repeats` rounds of DDIM (args.steps) and LCM (args.lcm_steps), with and without the
    ground-truth frame 0 as reference, over `shots` (EvalShots), alternating which sampler goes first.
    On a GPU the wall times are complete (every window's frames are copied to host memory before the
    render returns); the encoding share is not (its clock stops before the GPU finishes). Returns
    "load_average_before_after", "repeats", "median", "min", "max" of the result file."""
    from x2video.eval.conditions import Condition, build_edits
    from x2video.eval.runner import render_shot, warm_up
    from x2video.render.settings import RenderSettings

    refs = {s.name: build_edits(s.shot, s.name, Condition("full", reference=True), args.seed)[0] for s in shots}
    for sampler, r in renderers.items():
        warm_up(r, shots[0], sampler)
    steps = {"ddim": args.steps, "lcm": args.lcm_steps}
    load_before = os.getloadavg()
    repeats = []
    for i in range(args.repeats):
        order = ["ddim", "lcm"] if i % 2 == 0 else ["lcm", "ddim"]
        rows = []
        for sampler in order:
            for reference in (False, True):
                r = renderers[sampler]
                settings = RenderSettings(base="off", sampler=sampler, steps=steps[sampler], seed=args.seed, window=args.window,  # type: ignore[arg-type]
                                          replace_refs=args.replace_refs, noise=args.noise, noise_shared=args.noise_shared,
                                          ref_dc=args.ref_dc, resample=args.resample)
                secs = enc = 0.0
                frames = 0
                for s in shots:
                    _, t = render_shot(r, s, refs[s.name] if reference else None, settings)
                    secs, enc, frames = secs + t, enc + r.encode_seconds, frames + s.num_frames
                name = f"{sampler.upper()}-{steps[sampler]}" + (" + Ref." if reference else "")
                rows.append({"name": name, "sampler": sampler, "steps": steps[sampler], "reference": reference,
                             "seconds_per_frame": secs / frames, "encode_seconds_per_frame": enc / frames})
                print(f"repeat {i + 1}: {name:>14} {secs / frames:.3f} s/frame (encoding {enc / frames:.3f})", file=sys.stderr)
        repeats.append({"order": order, "rows": rows, **_ratios(rows)})
        print(f"repeat {i + 1}: " + ", ".join(f"{k} {repeats[-1][k]:.2f}x" for k in RATIOS), file=sys.stderr)
    return {
        "load_average_before_after": [list(load_before), list(os.getloadavg())],
        "repeats": repeats,
        "median": {k: statistics.median(r[k] for r in repeats) for k in RATIOS},
        "min": {k: min(r[k] for r in repeats) for k in RATIOS},
        "max": {k: max(r[k] for r in repeats) for k in RATIOS},
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_render_arguments(p)
    p.add_argument("--steps", type=int, default=20, help="DDIM steps (default 20)")
    p.add_argument("--lcm-steps", type=int, default=2, help="LCM steps (default 2)")
    p.add_argument("--repeats", type=int, default=3, help="DDIM/LCM pairs, alternating which goes first (default 3)")
    p.add_argument("--out", type=Path, default=RESULTS, help=f"JSON path (default {RESULTS})")
    args = p.parse_args(argv)
    if args.repeats < 1:
        p.error("--repeats must be at least 1")
    result = run_measure(args, measure)
    for k in RATIOS:
        print(f"{k:>24}: median {result['median'][k]:.2f}x (min {result['min'][k]:.2f}, max {result['max'][k]:.2f}) over {args.repeats} repeats")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
