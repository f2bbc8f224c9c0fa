"""Accuracy on path-traced shots nobody trained on: each tier beside the formula, per material class, and seconds per frame.

For every shot folder of `--data DATA/<split>/` (Cycles multi-layer EXR shots from `x2video dataset
make --renderer cycles` or `x2video dataset outside`, or any shot with rgb ground truth) and every
`--tiers` entry, the shot is rendered with `x2video.Renderer` (all channels, or with `--conditions
drop_irradiance` the irradiance dropped) and scored in the shot's own units (the renderer's frames
divided by the shot's exposure normalisation) against its ground truth:

- PSNR and SSIM on display images (`x2video.channels.tonemap`), TC with OpenCV DIS flow on the
  ground truth (as for outside footage: docs/ARCHITECTURE.md "Measuring it");
- PSNR per material class, from Cycles' own passes where the file has them: window/sky (no
  geometry), emitter (Emit), glass (TransCol), metal (metallic AOV > 0.5), glossy (roughness < 0.25),
  diffuse (the rest);
- seconds per frame of the render (model loaded, conditioning encoded inside the render).

"formula" is tier 0 (albedo x irradiance as the renderer computes it, zero inside masked regions);
"albedo_x_irradiance" is the plain product the channels give, measured beside every row.

    python -m bench.pathtraced --data DATA --split test [--tiers formula,residual,diffusion] [--weights DIR] [--name NAME]
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import torch

from bench.common import command, results_path
from bench.ptscore import display, render_timed, score, truth
from x2video.channels import tonemap
from x2video.eval.machine import machine_info
from x2video.io import load_shot
from x2video.io.atomic import write_json_atomic
from x2video.io.dataset import shot_dirs
from x2video.io.image import read_image
from x2video.io.paths import portable_path
from x2video.io.truth import ground_truth
from x2video.io.truth import summary as truth_summary
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.tiers import registry as tiers

CLASSES = ("diffuse", "glossy", "metal", "glass", "emitter", "window")


def material_classes(frame_file: Path, fr: dict[str, np.ndarray]) -> np.ndarray:
    """(H, W) index into CLASSES per pixel, from the frame's Cycles passes and our channels."""
    h, w = fr["albedo"].shape[:2]
    cls = np.zeros((h, w), np.int8)
    cls[fr["roughness"][..., 0] < 0.25] = CLASSES.index("glossy")
    cls[fr["metallic"][..., 0] > 0.5] = CLASSES.index("metal")
    try:
        img = read_image(frame_file)
        names = set(img.channel_names)
        for cname, pas in (("glass", "TransCol"), ("emitter", "Emit")):
            comps = [n for n in img.channel_names if n.split(".")[-2:-1] == [pas] and n[-1] in "RGB"]
            if len(comps) == 3:
                v = img.stack(comps).max(-1)
                cls[v > (0.1 if cname == "glass" else 0.02)] = CLASSES.index(cname)
        del names
    except (ValueError, OSError):
        pass
    cls[np.linalg.norm(fr["normal"], axis=-1) < 0.5] = CLASSES.index("window")
    return cls


def masked_psnr(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> tuple[float, int]:
    """(sum of squared errors, pixel count) over `mask` of display images, for pooling."""
    d = (pred[mask] - gt[mask]) ** 2
    return float(d.sum() / 3.0), int(mask.sum())


def condition_edits(shot, name: str, condition: str):
    """(Edits or None, per-frame (H, W) bool masks of the masked objects or None) of a `--conditions` entry: "all" (every
    channel), "drop_irradiance", or "mask_amr" (albedo, roughness and metallic of 3 visible objects masked out, drawn
    with seed 0 per shot as `x2video eval` draws them; `x2video.eval.conditions`)."""
    from x2video.eval.conditions import Condition, build_edits

    if condition == "all":
        return None, None
    if condition not in ("drop_irradiance", "mask_amr"):
        raise ValueError(f"unknown condition {condition!r} (all, drop_irradiance, mask_amr)")
    edits, desc = build_edits(shot, name, Condition(condition), seed=0)
    if condition != "mask_amr":
        return edits, None
    objects = [int(i) for i in desc["objects"]]
    return edits, [np.isin(shot.channel("ids", t)[..., 0], objects) for t in range(shot.num_frames)]


def mask_ring(mask: np.ndarray, px: int = 6) -> np.ndarray:
    """(H, W) bool: the band of `px` pixels just outside `mask`, where a composite of two tiers would show a seam."""
    import cv2

    grown = cv2.dilate(mask.astype(np.uint8), np.ones((2 * px + 1, 2 * px + 1), np.uint8)).astype(bool)
    return grown & ~mask


def render_tier(renderer: Renderer, shot, tier: str, edits=None, **overrides) -> tuple[list[np.ndarray], float]:
    """Frames and seconds of one tier (or "auto": what the product picks) with `edits`."""
    windowed = tier == "auto" or not tiers.get(tier).per_frame  # what may run the sampler takes the fast preset
    settings = RenderSettings(quality=tier, preset="fast" if windowed else None, **{"base": "off", **overrides})  # scored against the rgb
    return render_timed(renderer, shot, settings, edits)


LABELS = {"albedo_x_irradiance|all": "formula: albedo × irradiance", "formula|all": "tier 0 (formula)", "residual|all": "tier 1 (residual net)",
          "residual_guess|all": "tier 1, --guess-unseen (net's guess in sky and glass)",
          "auto|all": "auto (--quality auto: tier 1 where its guards hold, else the formula)",
          "diffusion|all": "tier 2 (diffusion, fast preset)", "diffusion|drop_irradiance": "tier 2, irradiance dropped",
          "formula|mask_amr": "tier 0 (formula), A\\|M\\|R of 3 objects masked out",
          "residual|mask_amr": "tier 1, A\\|M\\|R of 3 objects masked out", "diffusion|mask_amr": "tier 2, A\\|M\\|R of 3 objects masked out",
          "auto|mask_amr": "auto (tier 2 in the masks, tier 1 around), A\\|M\\|R of 3 objects masked out"}


def markdown(summary: dict) -> list[str]:
    """The summary as a Markdown table: PSNR, SSIM, TC, seconds per frame, then PSNR per material class."""
    classes = [c for c in CLASSES if any(v["pixel_share"].get(c) for v in summary.values())]
    in_masks = any("psnr_in_masks" in v for v in summary.values())
    ring = any("psnr_mask_ring" in v for v in summary.values())
    head = (["render", "PSNR↑", "SSIM↑", "TC↓", "s/frame↓"] + (["PSNR in masks↑"] if in_masks else []) + (["PSNR 6 px around masks↑"] if ring else [])
            + [f"{c} PSNR" for c in classes])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, v in summary.items():
        cells = [LABELS.get(key, key), f"{v['psnr']:.2f}", f"{v['ssim']:.4f}", "—" if v["tc"] is None else f"{v['tc']:.3f}",
                 f"{v['sec_per_frame']:.3f}"] + ([f"{v['psnr_in_masks']:.2f}" if "psnr_in_masks" in v else "—"] if in_masks else []) + (
                 [f"{v['psnr_mask_ring']:.2f}" if "psnr_mask_ring" in v else "—"] if ring else []) + [
                 "—" if v["psnr_by_material"][c] is None else f"{v['psnr_by_material'][c]:.2f}" for c in classes]
        lines.append("| " + " | ".join(cells) + " |")
    share = ", ".join(f"{c} {100 * next(iter(summary.values()))['pixel_share'][c]:.1f} %" for c in classes)
    lines.append("")
    lines.append(f"Pixel shares: {share}.")
    return lines


def evaluate(renderer: Renderer, shots: list[Path], runs: list[tuple[str, str, str, dict]]) -> tuple[dict, list[dict]]:
    """(summary per key, per-shot rows) of `runs` (key, tier, condition, RenderSettings overrides) on the shot folders
    `shots`, each scored in its own units against its ground truth, "albedo_x_irradiance|all" beside them."""
    rows: dict[str, dict] = {}
    per_shot = []
    for sp in shots:
        shot = load_shot(sp)
        s = float(shot.info.irradiance_scale)
        files = sorted(sp.glob("*.exr"))
        gts, forms, classes = truth(shot), [], []
        for t in range(shot.num_frames):
            fr = shot.frame(t)
            forms.append(tonemap(fr["albedo"] * fr["irradiance"] / s))
            classes.append(material_classes(files[t], fr) if len(files) == shot.num_frames else np.zeros(gts[-1].shape[:2], np.int8))
        tc_gt_ok = shot.num_frames >= 2
        results = {"albedo_x_irradiance|all": (forms, 0.0)}
        conds = {cond: condition_edits(shot, sp.name, cond) for cond in {c for _, _, c, _ in runs}}
        rings = [mask_ring(m) for m in conds.get("mask_amr", (None, None))[1] or []]  # the band around the masks, per frame
        for key, tier, cond, overrides in runs:
            frames, secs = render_tier(renderer, shot, tier, conds[cond][0], **overrides)
            results[key] = (display(frames, s), secs)
        shot_row = {"shot": f"{sp.parent.name}/{sp.name}", "frames": shot.num_frames, "size": list(shot.size[::-1]),
                    "truth": ground_truth(shot).label}
        for key, (disp, secs) in results.items():
            r = rows.setdefault(key, {"psnr": [], "ssim": [], "tc": [], "sec_per_frame": [], "sse": np.zeros(len(CLASSES)), "npx": np.zeros(len(CLASSES)),
                                      "sse_mask": 0.0, "npx_mask": 0, "sse_ring": 0.0, "npx_ring": 0})
            m = score(disp, gts)
            masks = conds.get(key.split("|")[1], (None, None))[1]
            for p, g, mk in zip(disp, gts, masks or []):  # inside the masked objects (mask_amr): what had to be generated
                e, n = masked_psnr(p, g, mk)
                r["sse_mask"] += e
                r["npx_mask"] += n
            # the 6-pixel band around the mask_amr objects, in every row: where auto's composite meets tier 1 (a seam
            # shows as a lower PSNR there than tier 1's on all channels)
            for p, g, ring in zip(disp, gts, rings):
                e, n = masked_psnr(p, g, ring)
                r["sse_ring"] += e
                r["npx_ring"] += n
            tc = m["tc"] if tc_gt_ok else None
            for p, g, c in zip(disp, gts, classes):
                for k in range(len(CLASSES)):
                    e, n = masked_psnr(p, g, c == k)
                    r["sse"][k] += e
                    r["npx"][k] += n
            r["psnr"].append(m["psnr"])
            r["ssim"].append(m["ssim"])
            if tc is not None:
                r["tc"].append(float(tc))
            r["sec_per_frame"].append(secs / shot.num_frames)
            shot_row[key] = {"psnr": round(m["psnr"], 3), "ssim": round(m["ssim"], 4), "tc": None if tc is None else round(float(tc), 3)}
        per_shot.append(shot_row)
        print(json.dumps(shot_row), flush=True)
    summary = {}
    for key, r in rows.items():
        summary[key] = {
            "psnr": round(float(np.mean(r["psnr"])), 3), "ssim": round(float(np.mean(r["ssim"])), 4),
            "tc": round(float(np.mean(r["tc"])), 3) if r["tc"] else None,
            "sec_per_frame": round(float(np.mean(r["sec_per_frame"])), 4),
            "psnr_by_material": {c: (round(10 * math.log10(n / max(e, 1e-12)), 2) if n else None) for c, e, n in zip(CLASSES, r["sse"], r["npx"])},
            "pixel_share": {c: round(float(n / max(r["npx"].sum(), 1)), 4) for c, n in zip(CLASSES, r["npx"])},
        }
        if r["npx_mask"]:
            summary[key]["psnr_in_masks"] = round(10 * math.log10(r["npx_mask"] / max(r["sse_mask"], 1e-12)), 2)
        if r["npx_ring"]:
            summary[key]["psnr_mask_ring"] = round(10 * math.log10(r["npx_ring"] / max(r["sse_ring"], 1e-12)), 2)
    return summary, per_shot


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="data set folder (DATA/<split>/<shot>/) or a folder of shots with --split ''")
    ap.add_argument("--split", default="test")
    ap.add_argument("--tiers", default="formula,residual,diffusion", help="comma-separated: formula, residual, diffusion")
    ap.add_argument("--conditions", default="all", help="comma-separated: all, drop_irradiance, mask_amr (3 objects' A|M|R masked out; "
                    "the formula and tier 1 are rendered under it too, and PSNR inside the masks is reported)")
    ap.add_argument("--weights", default=None, help="model folder (default: the shipped weights)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--max-shots", type=int, default=0)
    ap.add_argument("--seam-px", type=float, default=None,
                    help="auto's seam in pixels inside a generated region (x2video.tiers.regions.SEAM_PX; 0: a hard edge; negative: "
                         "the earlier outward feather of that many pixels): to choose it on validation rooms")
    ap.add_argument("--name", default=None, help="results file bench/results/pathtraced/NAME.json (default: <data name>_<split>)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    from x2video.tiers import regions

    if args.seam_px is not None:
        regions.SEAM_PX = args.seam_px

    from x2video.weights import load_model

    model = load_model(args.weights)
    weights = Path(args.weights) if args.weights else Path("shipped")
    renderer = Renderer(model)
    root = Path(args.data) / args.split if args.split else Path(args.data)
    shots = shot_dirs(root)
    if args.max_shots:
        shots = shots[: args.max_shots]
    names = [t for t in args.tiers.split(",") if t]
    conditions = [c for c in args.conditions.split(",") if c]
    runs = [(f"{t}|{cond}", t, cond, {}) for cond in conditions for t in names
            if tiers.get(t).generative or cond == "all" or (cond == "mask_amr" and not tiers.get(t).generative)]  # the per-frame tiers beside it
    if "mask_amr" in conditions and any(tiers.get(t).generative for t in names):  # auto's composite under the masks
        runs.append(("auto|mask_amr", "auto", "mask_amr", {}))
    if tiers.RESIDUAL in names and "all" in conditions:
        runs.append(("auto|all", "auto", "all", {}))  # what --quality auto renders of the whole shot: tier 1 under its guards
        runs.append(("residual_guess|all", "residual", "all", {"guess_unseen": True}))  # tier 1 guessing where the channels hold no light
    summary, per_shot = evaluate(renderer, shots, runs)
    out = {"format": "x2video-pathtraced", "command": command("pathtraced", argv), "data": portable_path(args.data), "split": args.split,
           "shots": len(shots), "truth": truth_summary(r["truth"] for r in per_shot),
           "weights": portable_path(weights) if args.weights else "shipped", "threads": args.threads,
           "seam_px": regions.SEAM_PX,
           "residual_net": model.residual_net is not None, "machine": machine_info(model.device),
           "note": "PSNR/SSIM on tonemap (clip, sRGB) in the shot's units; TC = warping error / ground truth's, DIS flow; "
                   "per-material PSNR pools squared errors over the class's pixels; 'formula' = tier 0 (classical shading), "
                   "'albedo_x_irradiance' = the plain product",
           "summary": summary, "shots_detail": per_shot}
    dest = results_path("pathtraced", args.name or f"{Path(args.data).name}_{args.split or 'all'}")
    dest.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(dest, out)
    from x2video.io.atomic import write_text_atomic

    write_text_atomic(dest.with_suffix(".md"), "\n".join(markdown(summary) + ["", f"Truth: {out['truth']}."]) + "\n")
    for key, v in summary.items():
        print(f"{key:28s} PSNR {v['psnr']:6.2f}  SSIM {v['ssim']:.4f}  TC {v['tc']}  s/frame {v['sec_per_frame']:.3f}  {v['psnr_by_material']}")
    print(f"wrote {dest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
