"""PSNR and TC of noise seedings over several seeds: per-window noise against per-frame noise with a part shared
by every frame of the shot (`RenderSettings.noise`, `.noise_shared`), on held-out shots.

One evaluation uses one seed. With noise shared across a shot, every frame of a shot draws the same
guess of what the channels leave open (the lighting without irradiance, the materials inside an
A|M|R mask), so a 4-shot mean moves more from seed to seed than with independent noise; this bench
renders each condition with several seeds and pairs the settings seed by seed. The image model
renders frames independently, so for it a seeding cannot change the expected PSNR of a frame at all:
its rows (`--image`) show how far one seed's mean can stray by chance.

    python -m bench.noise_prior --data DATA [--weights RUN_OR_DIR] [--rooms 4] [--frames 17]
        [--conditions full,drop_irradiance,mask_amr] [--seeds 0,1,2] [--settings window,frame:0.95]
        [--image] [--threads 1] [--out bench/results/noise_prior/noise_prior.json]

A setting is `window` or `frame:F` (per-frame noise, fraction F shared). Masks of Mask A|M|R are drawn
with seed 0 whatever the noise seed, so the conditions stay the same across seeds. PSNR: mean over
frames and shots (as `x2video eval`); TC: mean flow-warping error of the prediction over all frame
pairs of all shots / that of the ground truth (exact motion). Recursive Sampling, DDIM-20.

Writes {"format": "x2video-noise-prior", "command", "machine", "weights", "data", "settings",
"results": {model: {condition: {setting: {"psnr", "tc", "per_seed": {seed: {"psnr", "tc"}}}}}},
"paired": {model: {condition: {setting: {"psnr_diff", "tc_ratio", "per_seed_psnr_diff", "per_seed_tc_ratio"}}}}}
with the differences taken against the first setting.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bench.common import add_render_arguments, load_models, result_header, results_path, run_measure

RESULTS = results_path("noise_prior")


def parse_setting(token: str) -> tuple[str, float]:
    """'window' -> ('window', 0.0); 'frame:0.95' -> ('frame', 0.95)."""
    token = token.strip()
    if token == "window":
        return "window", 0.0
    kind, _, frac = token.partition(":")
    if kind != "frame" or not frac:
        raise argparse.ArgumentTypeError(f"setting {token!r}: use 'window' or 'frame:F' with F in [0, 1]")
    f = float(frac)
    if not 0.0 <= f <= 1.0:
        raise argparse.ArgumentTypeError(f"setting {token!r}: the shared fraction must lie in [0, 1]")
    return "frame", f


def measure(args: argparse.Namespace) -> dict:
    from x2video.channels import tonemap
    from x2video.eval.conditions import build_edits, parse_condition
    from x2video.eval.data import load_eval_shots
    from x2video.eval.runner import render_shot
    from x2video.metrics.image import psnr
    from x2video.metrics.temporal import ground_truth_flows, warping_errors
    from x2video.render.renderer import Renderer
    from x2video.render.settings import RenderSettings

    if not args.image:
        args.image_weights = None
    elif args.image_weights is None:  # the image model shipped beside the video model
        from x2video.weights import shipped_weights

        base = args.weights if args.weights is not None else shipped_weights()
        args.image_weights = None if base is None else Path(base) / "image"
    models, _, size, _ = load_models(args, with_image=args.image)
    shots = load_eval_shots(args.data, args.split, args.rooms, args.frames, size)
    settings = [parse_setting(s) for s in args.settings.split(",")]
    names = [s.strip() for s in args.settings.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    runs = [("video", models.video, args.window)]
    if args.image:
        if models.image is None:
            raise ValueError("--image: no image-stage weights (pass --image-weights)")
        runs.append(("image", models.image, max(2, min(args.frames, 32))))
    gt = {s.name: [tonemap(g) for g in s.gt] for s in shots}
    flows = {s.name: ground_truth_flows(gt[s.name], s.motion)[0] for s in shots}
    gt_err = {s.name: warping_errors(gt[s.name], flows[s.name]).errors for s in shots}
    results: dict = {}
    paired: dict = {}
    for model_name, model, window in runs:
        renderer = Renderer(model)
        for cond_name in args.conditions.split(","):
            condition = parse_condition(cond_name)
            edits = {s.name: build_edits(s.shot, s.name, condition, 0)[0] for s in shots}
            per = results.setdefault(model_name, {}).setdefault(cond_name, {})
            for name, (noise, shared) in zip(names, settings):
                per_seed = {}
                for seed in seeds:
                    rs = RenderSettings(base="off", sampler="ddim", steps=args.steps, seed=seed, window=window, replace_refs=args.replace_refs,  # type: ignore[arg-type]
                                        noise=noise, noise_shared=shared, ref_dc=args.ref_dc, resample=args.resample)  # type: ignore[arg-type]
                    ps, pe, ge = [], [], []
                    for s in shots:
                        frames, _ = render_shot(renderer, s, edits[s.name], rs)
                        shown = [tonemap(f) for f in frames]
                        ps.extend(psnr(a, b) for a, b in zip(shown, gt[s.name]))
                        pe.append(warping_errors(shown, flows[s.name]).errors)
                        ge.append(gt_err[s.name])
                    pred, ref = np.concatenate(pe), np.concatenate(ge)
                    ok = np.isfinite(pred) & np.isfinite(ref)
                    per_seed[str(seed)] = {"psnr": float(np.mean(ps)), "tc": float(pred[ok].mean() / ref[ok].mean())}
                    print(f"{model_name} {cond_name} {name} seed {seed}: PSNR {per_seed[str(seed)]['psnr']:.3f} dB, "
                          f"TC {per_seed[str(seed)]['tc']:.3f}", file=sys.stderr)
                per[name] = {"psnr": float(np.mean([v["psnr"] for v in per_seed.values()])),
                             "tc": float(np.mean([v["tc"] for v in per_seed.values()])), "per_seed": per_seed}
            base = per[names[0]]["per_seed"]
            pc = paired.setdefault(model_name, {}).setdefault(cond_name, {})
            for name in names[1:]:
                this = per[name]["per_seed"]
                d = [this[k]["psnr"] - base[k]["psnr"] for k in base]
                r = [this[k]["tc"] / base[k]["tc"] for k in base]
                pc[name] = {"psnr_diff": float(np.mean(d)), "tc_ratio": float(np.mean(r)), "per_seed_psnr_diff": d, "per_seed_tc_ratio": r}
    return {
        **result_header("noise-prior", "noise_prior", args, models, shots, size),
        "settings": {"conditions": args.conditions.split(","), "seeds": seeds, "noise": names, "steps": args.steps,
                     "scheme": "recursive", "sampler": "ddim"},
        "results": results,
        "paired": paired,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_render_arguments(p)
    p.set_defaults(rooms=4)
    p.add_argument("--image-weights", type=Path, help="image-stage run or folder (with --image; default: the video folder's image/)")
    p.add_argument("--image", action="store_true", help="also render with the image model (frames independent)")
    p.add_argument("--conditions", default="full,drop_irradiance,mask_amr", help="KIND[+text][+ref], comma-separated")
    p.add_argument("--seeds", default="0,1,2", help="noise seeds, comma-separated (default 0,1,2)")
    p.add_argument("--settings", default="window,frame:0.95", help="'window' and/or 'frame:F', comma-separated; the first is the baseline")
    p.add_argument("--steps", type=int, default=20, help="DDIM steps (default 20)")
    p.add_argument("--out", type=Path, default=RESULTS, help=f"JSON path (default {RESULTS})")
    args = p.parse_args(argv)
    for s in args.settings.split(","):
        parse_setting(s)  # bad settings fail before the model loads
    result = run_measure(args, measure)
    for model_name, conds in result["paired"].items():
        for cond, per in conds.items():
            base = result["results"][model_name][cond][args.settings.split(",")[0].strip()]
            for name, v in per.items():
                this = result["results"][model_name][cond][name]
                print(f"{model_name:>5} {cond:<20} {name:<11}: PSNR {this['psnr']:.3f} vs {base['psnr']:.3f} dB "
                      f"(paired {v['psnr_diff']:+.3f}, per seed " + " ".join(f"{x:+.2f}" for x in v["per_seed_psnr_diff"]) +
                      f"), TC {this['tc']:.3f} vs {base['tc']:.3f} (x{v['tc_ratio']:.3f})")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
