"""Probe (not project code, ships nothing): should keyframe-mode windows with one reference (the
user's frame; at the shot's ends, the seam pass's one-sided windows) also be mean-anchored, to that
reference's latent mean over its inferred region, with strength KEY_STRENGTH (default 0.5)?
Interpolation windows keep the renderer's `mean_anchor`. Runs bench.recursive_seams patched:

    KEY_STRENGTH=0.5 python research/experiments/key_anchor_probe.py --data VAL --split val --rooms 2 \
        --threads 1 --schemes recursive --out research/experiments/results/key_anchor_0.5_drop_ref_val.json

Result (model card preface, "Mean anchoring and the seam pass"): TC better, PSNR below sequential's,
so it was not kept. The JSON's `command` names the bench, which this script ran patched.
"""
import os, sys
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: the bench package
import torch
import x2video.render.renderer as R

KS = float(os.environ.get("KEY_STRENGTH", "0.5"))
orig = R.mean_anchor

def patched(window, strength, ref, offset, regions):
    if window.mode == "key" and len(window.ref_positions) == 1 and KS > 0:
        (p0,) = window.ref_positions
        if float(regions[p0].sum()) < 1.0:
            return None
        gen = [p for p in window.generate_positions if p != p0 and float(regions[p].sum()) >= 1.0]
        if not gen:
            return None
        w_gen = torch.stack([regions[p] for p in gen])
        target = R.region_mean(ref[p0], regions[p0])[None]
        def anchor(x0, i):
            x0 = x0.clone()
            now = R.region_mean(x0[gen] + offset[gen], w_gen)
            x0[gen] += (KS * (target - now)[..., None, None] * w_gen.to(x0.device)[:, None]).to(x0.dtype)
            return x0
        return anchor
    return orig(window, strength, ref, offset, regions)

R.mean_anchor = patched
import bench.recursive_seams as recursive_seams
sys.exit(recursive_seams.main(sys.argv[1:]))
