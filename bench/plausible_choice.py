"""Choosing auto's guard on validation rooms against their truth: every pair of bounds, scored (issue 49, item 4).

`bench.plausible_bound` says how far tier 1 corrects the formula; this bench says what each choice of
`x2video.model.plausible`'s bounds gives: for each validation shot, tier 1's frames as the product renders them
without the guard (quality 'residual', the unseen-light rule on) and the formula's, then, for every tile bound and
frame bound of the grid, auto's frames (`plausible.guard` with those bounds) scored against the shot's truth apart
(PSNR on display images, the mean over frames, as `bench.pathtraced`). The rule that picks the shipped pair: no shot
under the formula by more than `AUTO_BELOW_DB` (auto's promise), then the highest mean PSNR over the shots; the
result says which pair that is and whether it is the one the code holds (`TILE_BOUND`, `FRAME_BOUND`).

Validation shots only: `--split` must be 'val' (a test split is refused), so that no bound is chosen on the rooms the
card reports.

    python -m bench.plausible_choice --data DATA/cycles-v3-s41-160x112-16spp --split val [--tiles 0.8,0.9,1.0,1.2] [--frames 0.2,0.3]

Writes bench/results/plausible_choice/<data name>_<split>.json and .md.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bench.stability import AUTO_BELOW_DB  # auto's promise, as the stability grid checks it

TILES = (0.5, 0.7, 0.8, 0.85, 0.9, 0.95, 1.0, 1.2, 1.5, 2.0, 3.0)
FRAMES = (0.1, 0.15, 0.2, 0.3, 0.5)


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split(",") if v.strip())


def shot_psnr(frames: list[np.ndarray], scale: float, gts: list[np.ndarray]) -> float:
    from bench.ptscore import display
    from x2video.metrics.image import psnr

    return float(np.mean([psnr(d, g) for d, g in zip(display(frames, scale), gts)]))


def choose(rows: list[dict], tiles: tuple[float, ...], frames: tuple[float, ...]) -> dict:
    """The summary of per-shot rows ({'formula': dB, 'tier1': dB, 'auto': {(tile, frame): dB}}): per pair its mean,
    worst shot against the formula and shots under the promise, and the pair the rule picks (None when none keeps it)."""
    grid = []
    for tb in tiles:
        for fb in frames:
            d = [r["auto"][tb, fb] - r["formula"] for r in rows]
            grid.append({"tile_bound": tb, "frame_bound": fb, "psnr": round(float(np.mean([r["auto"][tb, fb] for r in rows])), 3),
                         "worst_vs_formula_db": round(min(d), 3), "shots_under": int(sum(v < -AUTO_BELOW_DB for v in d))})
    ok = [g for g in grid if g["shots_under"] == 0]
    best = max(ok, key=lambda g: (g["psnr"], -g["tile_bound"], -g["frame_bound"])) if ok else None
    return {"grid": grid, "chosen": best}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="data set folder (DATA/<split>/<shot>/, each with its truth apart)")
    ap.add_argument("--split", default="val")
    ap.add_argument("--tiles", default=",".join(f"{v:g}" for v in TILES), help="tile bounds to try (|log ratio|)")
    ap.add_argument("--frames", default=",".join(f"{v:g}" for v in FRAMES), help="frame bounds to try (|log ratio|)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--name", default=None, help="bench/results/plausible_choice/NAME.json (default: <data name>_<split>)")
    args = ap.parse_args(argv)
    if args.split != "val":
        raise SystemExit(f"--split {args.split!r}: the guard's bounds are chosen on validation rooms only ('val'), never on the"
                         " rooms the card reports")
    tiles, frames = _floats(args.tiles), _floats(args.frames)
    if not tiles or not frames:
        raise SystemExit("--tiles and --frames need at least one bound each")

    import torch

    from bench.common import clean_json, command, results_path
    from bench.ptscore import render_timed, truth, truth_label
    from x2video import Renderer, RenderSettings
    from x2video.eval.machine import machine_info
    from x2video.io import load_shot
    from x2video.io.atomic import write_json_atomic, write_text_atomic
    from x2video.io.dataset import shot_dirs
    from x2video.io.paths import portable_path
    from x2video.model import plausible
    from x2video.weights import load_model

    torch.set_num_threads(args.threads)
    dirs = shot_dirs(args.data, args.split)
    if not dirs:
        raise SystemExit(f"{Path(args.data) / args.split}: no shots")
    model = load_model()
    renderer = Renderer(model, retain=False)
    rows, shots = [], []
    for sp in dirs:
        shot = load_shot(sp)
        shots.append(shot)
        scale = float(shot.info.irradiance_scale)
        tier1, _ = render_timed(renderer, shot, RenderSettings(quality="residual", base="off"))
        form, _ = render_timed(renderer, shot, RenderSettings(quality="formula", base="off"))
        gts = truth(shot)
        auto = {(tb, fb): shot_psnr([plausible.guard(a, b, tile_bound=tb, frame_bound=fb)[0] for a, b in zip(tier1, form)], scale, gts)
                for tb in tiles for fb in frames}
        rows.append({"shot": sp.name, "formula": shot_psnr(form, scale, gts), "tier1": shot_psnr(tier1, scale, gts), "auto": auto})
        print(f"{sp.name}: formula {rows[-1]['formula']:.2f}, tier 1 {rows[-1]['tier1']:.2f}", flush=True)
    summary = choose(rows, tiles, frames)
    held = {"tile_bound": plausible.TILE_BOUND, "frame_bound": plausible.FRAME_BOUND}
    chosen = summary["chosen"]
    out = {"format": "x2video-plausible-choice", "command": command("plausible_choice", argv), "data": portable_path(args.data),
           "split": args.split, "shots": len(rows), "truth": truth_label(shots), "machine": machine_info(model.device),
           "rule": f"no shot under the formula by more than {AUTO_BELOW_DB} dB, then the highest mean PSNR",
           "formula_psnr": round(float(np.mean([r["formula"] for r in rows])), 3),
           "tier1_psnr": round(float(np.mean([r["tier1"] for r in rows])), 3),
           "tier1_worst_vs_formula_db": round(min(r["tier1"] - r["formula"] for r in rows), 3),
           "held_by_the_code": held, "chosen": chosen,
           "code_holds_the_choice": chosen is not None and (chosen["tile_bound"], chosen["frame_bound"]) == (held["tile_bound"], held["frame_bound"]),
           "grid": summary["grid"],
           "per_shot": [{"shot": r["shot"], "formula": round(r["formula"], 3), "tier1": round(r["tier1"], 3),
                         "auto": {f"{tb:g}/{fb:g}": round(v, 3) for (tb, fb), v in r["auto"].items()}} for r in rows]}
    dest = results_path("plausible_choice", args.name or f"{Path(args.data).name}_{args.split}")
    dest.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(dest, clean_json(out))
    lines = [f"# Auto's guard bounds on {len(rows)} validation shots ({out['truth']})", "",
             f"formula {out['formula_psnr']:.2f} dB, tier 1 unguarded {out['tier1_psnr']:.2f} (worst shot {out['tier1_worst_vs_formula_db']:+.2f}"
             " against the formula). Rule: " + out["rule"] + ".", "",
             "| tile bound | frame bound | auto PSNR | worst shot − formula | shots under −0.2 dB |", "|---|---|---|---|---|"]
    for g in summary["grid"]:
        mark = " **(chosen)**" if g is chosen else ""
        lines.append(f"| {g['tile_bound']:g} | {g['frame_bound']:g} | {g['psnr']:.2f}{mark} | {g['worst_vs_formula_db']:+.2f} | {g['shots_under']} |")
    lines += ["", f"The code holds tile {held['tile_bound']:g}, frame {held['frame_bound']:g}: "
              + ("the chosen pair." if out["code_holds_the_choice"] else "not the chosen pair.")]
    write_text_atomic(dest.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines[-3:]))
    print(f"wrote {dest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
