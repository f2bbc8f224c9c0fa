"""Where the formula's error lies on path-traced shots: the PSNR that each light term it lacks would add.

For Cycles shots (multi-layer EXRs with the light passes) of `--data DATA/<split>/`, every `--step`-th frame is
scored in the shot's units against its ground truth (its truth apart, `SHOT/truth/`, when it has one; display
images, `x2video.channels.tonemap`, as `bench.pathtraced`), for:

- the formula, albedo x irradiance;
- the formula plus Cycles' own glossy passes (GlossCol x (GlossDir + GlossInd)), transmission passes, emission and
  environment: what a perfect tier 1 could add from each term (an upper bound per term);
- the formula with the pixels whose channels hold no light (`x2video.model.residual.unseen_light`: sky, glass,
  mirrors) set to the ground truth's mean over them in that frame (one colour a frame: what a perfect guess of "the
  outside's colour" would add), and set to the ground truth itself.

No network runs: it says what a renderer fed these channels could gain where, and so which hint or tier to build.

    python -m bench.light_budget --data DATA --split test [--step 4] [--name NAME]
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from bench.common import command, results_path
from x2video.channels import INTRINSIC, tonemap
from x2video.formula import formula
from x2video.io import load_shot
from x2video.io.atomic import write_json_atomic, write_text_atomic
from x2video.io.image import read_image
from x2video.io.paths import portable_path
from x2video.io.truth import ground_truth
from x2video.io.truth import summary as truth_summary
from x2video.model.residual import unseen_light

CASES = ("formula", "+ glossy passes", "+ transmission passes", "+ emission and environment", "+ glossy and transmission",
         "+ every pass", "unseen pixels: the frame's mean truth", "unseen pixels: the truth", "unseen truth + glossy passes")


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return 10 * math.log10(1 / max(float(np.mean((tonemap(a) - tonemap(b)) ** 2)), 1e-12))


def frame_cases(fr: dict, passes, scale: float, gt: np.ndarray | None = None) -> dict[str, float]:
    """PSNR of each case of `CASES` for one frame (`fr` from the loader, `passes(name)` -> (H, W, 3) Cycles pass),
    against `gt` (the shot's truth apart, `x2video.io.truth`; default the frame's own rgb, the passes' Combined)."""
    gt = fr["rgb"] if gt is None else gt
    ch = {k: fr[k] for k in INTRINSIC}
    base = formula(ch) / scale  # the loader normalised irradiance by `scale`; the ground truth is in the shot's units
    gloss = passes("GlossCol") * (passes("GlossDir") + passes("GlossInd"))
    trans = passes("TransCol") * (passes("TransDir") + passes("TransInd"))
    emit = passes("Emit") + passes("Env")
    unseen = unseen_light(ch)
    unseen = np.zeros(gt.shape[:2], bool) if unseen is None else unseen
    mean_fill, true_fill = base.copy(), base.copy()
    if unseen.any():
        mean_fill[unseen] = gt[unseen].mean(0)
        true_fill[unseen] = gt[unseen]
    gloss_fill = np.where(unseen[..., None], gt, base + gloss)
    imgs = (base, base + gloss, base + trans, base + emit, base + gloss + trans, base + gloss + trans + emit, mean_fill, true_fill, gloss_fill)
    return {c: psnr(v, gt) for c, v in zip(CASES, imgs)} | {"unseen_share": float(unseen.mean())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--step", type=int, default=4, help="score every STEP-th frame of each shot")
    ap.add_argument("--name", default=None, help="bench/results/light_budget/NAME.json (default: <data name>_<split>)")
    args = ap.parse_args(argv)
    if args.step < 1:
        raise SystemExit(f"--step must be at least 1 (got {args.step})")
    root = Path(args.data) / args.split
    shots = sorted(p for p in root.iterdir() if (p / "shot.json").is_file()) if root.is_dir() else []
    if not shots:
        raise SystemExit(f"{root}: no shots (folders with shot.json)")
    rows: list[dict[str, float]] = []
    labels: list[str] = []
    for sp in shots:
        shot = load_shot(sp)
        gt = ground_truth(shot, sp)  # a truth apart (SHOT/truth/) when the shot has one: the passes share no samples with it
        labels.append(gt.label)
        files = sorted(sp.glob("*.exr"))
        if len(files) != shot.num_frames:
            raise SystemExit(f"{sp}: {len(files)} EXR files for {shot.num_frames} frames; this bench needs Cycles' multi-layer EXRs")
        for t in range(0, shot.num_frames, args.step):
            img = read_image(files[t])
            names = set(img.channel_names)

            def passes(p: str) -> np.ndarray:
                comps = [f"{p}.{c}" for c in "RGB"]
                if not all(c in names for c in comps):
                    raise SystemExit(f"{files[t]}: lacks the Cycles pass {p}")
                return img.stack(comps)

            rows.append(frame_cases(shot.frame(t), passes, float(shot.info.irradiance_scale), gt.frame(t)))
    summary = {c: round(float(np.mean([r[c] for r in rows])), 2) for c in CASES}
    summary["unseen_share"] = round(float(np.mean([r["unseen_share"] for r in rows])), 4)
    out = {"format": "x2video-light-budget", "command": command("light_budget", argv), "data": portable_path(args.data),
           "split": args.split, "shots": len(shots), "frames": len(rows), "summary": summary,
           "truth": truth_summary(labels),
           "note": "mean per-frame PSNR (tonemap: clip, sRGB) in the shot's units; 'unseen' = residual.unseen_light of the channels"}
    dest = results_path("light_budget", args.name or f"{Path(args.data).name}_{args.split}")
    dest.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(dest, out)
    lines = ["| case | PSNR | vs formula |", "|---|---|---|"]
    lines += [f"| {c} | {summary[c]:.2f} | {summary[c] - summary['formula']:+.2f} |" for c in CASES]
    lines += ["", f"{len(rows)} frames of {len(shots)} shots; unseen pixels {100 * summary['unseen_share']:.1f} % of a frame;"
                  f" truth: {out['truth']}."]
    write_text_atomic(dest.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {dest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
