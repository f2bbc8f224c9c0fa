"""Probe (not project code, ships nothing): does matching each latent channel's standard deviation too,
not only its mean, help Recursive Sampling's interpolation windows hold their references?

Replaces the renderer's `mean_anchor` (`RenderSettings.ref_dc`) with a full latent AdaIN toward the
linear interpolation of the two references' per-channel mean and spread inside the inferred region
(STD_STRENGTH, default 1, is how far the spread moves), then runs bench.recursive_seams with the
arguments given:

    STD_STRENGTH=1 python research/experiments/std_anchor_probe.py --data VAL --split val --rooms 2 \
        --threads 1 --schemes recursive --out research/experiments/results/std_anchor_drop_ref_val.json

Result (model card preface, "Mean anchoring and the seam pass"): worse than the mean alone on both
PSNR and TC, so it was not kept. The JSON's `command` names the bench, which this script ran patched.
"""
import os, sys
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: the bench package
import torch
import x2video.render.renderer as R

STD = float(os.environ.get("STD_STRENGTH", "1"))


def mean_std_anchor(window, strength, ref, offset, regions):
    where = R.anchor_positions(window, strength, regions)
    if where is None:
        return None
    p0, p1, gen = where

    def stats(z, w):  # (..., 4, h, w), (..., h, w) -> mean and standard deviation, (..., 4) each
        m = R.region_mean(z, w)
        return m, R.region_mean((z.float() - m[..., None, None]) ** 2, w).clamp_min(1e-8).sqrt()

    w_gen = torch.stack([regions[p] for p in gen])
    m0, s0 = stats(ref[p0], regions[p0]); m1, s1 = stats(ref[p1], regions[p1])
    lam = torch.tensor([(p - p0) / (p1 - p0) for p in gen], device=ref.device)[:, None]
    tm = (1 - lam) * m0 + lam * m1
    ts = (1 - lam) * s0 + lam * s1

    def anchor(x0, i):
        x0 = x0.clone()
        z = x0[gen] + offset[gen]
        m, s = stats(z, w_gen)
        scale = 1 + STD * (ts / s - 1)
        newz = (z - m[..., None, None]) * scale[..., None, None] + m[..., None, None] + strength * (tm - m)[..., None, None]
        wg = w_gen.to(x0.device)[:, None]
        x0[gen] = (x0[gen] + wg * (newz - z)).to(x0.dtype)
        return x0
    return anchor

R.mean_anchor = mean_std_anchor
import bench.recursive_seams as recursive_seams
sys.exit(recursive_seams.main(sys.argv[1:]))
