"""Probe (2026-12-03, docs/evaluations/2026-12-03-tier1-working-size.md): tier 1 run at a coarser working scale, its log-space correction upsampled onto the full-res formula.
Usage: python research/experiments/tier1_scale_probe.py DATA SPLIT SCALES   (e.g. DATA/pt1024 test 1,2,4), from the repository root.
"""
import sys, time, json
from pathlib import Path
import numpy as np, torch, cv2
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root (bench/)
from bench.ptscore import display, render_timed, score, truth
from x2video.io.dataset import shot_dirs
from x2video.io import load_shot
from x2video.render.settings import RenderSettings
from x2video.render.renderer import Renderer
from x2video.tiers import registry as tiers
from x2video.model import residual as R
from x2video.weights import load_model

torch.set_num_threads(2)
orig = tiers._net_frames
SCALE = [1.0]

def down(v, hw):
    if v is None: return None
    v = np.asarray(v, np.float32)
    out = cv2.resize(v, (hw[1], hw[0]), interpolation=cv2.INTER_AREA)
    return out if out.ndim == v.ndim else out[..., None]

def scaled(net, conds, device, batch):
    s = SCALE[0]
    if s == 1.0:
        return orig(net, conds, device, batch)
    out = []
    for c in conds:
        ch = c.channels
        H, W = next(np.shape(v)[:2] for v in ch.values() if v is not None)
        f = net.cfg.factor
        h = max(f, int(round(H / s / f)) * f); w = max(f, int(round(W / s / f)) * f)
        low = {k: down(v, (h, w)) for k, v in ch.items()}
        if low.get("normal") is not None:
            n = low["normal"]; low["normal"] = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6) * (np.linalg.norm(n, axis=-1, keepdims=True) > 0.25)
        x, sh = R.features(low, (h, w))
        with torch.inference_mode():
            y = R.apply(net, torch.from_numpy(x)[None], torch.from_numpy(sh)[None])[0].numpy()  # (3,h,w)
        delta = np.log1p(np.maximum(y, 0)) - np.log1p(np.maximum(sh, 0))
        d = cv2.resize(delta.transpose(1, 2, 0), (W, H), interpolation=cv2.INTER_LINEAR)
        base = R.formula(ch, (H, W))
        out.append(np.maximum(np.expm1(np.log1p(np.maximum(base, 0)) + d), 0).astype(np.float32))
    return out

tiers._net_frames = scaled
model = load_model()
data, split, scales = Path(sys.argv[1]), sys.argv[2], [float(v) for v in sys.argv[3].split(",")]
rows = {}
for sd in shot_dirs(data / split):
    shot = load_shot(sd)
    gts = truth(shot)
    r = Renderer(model)
    f0, _ = render_timed(r, shot, RenderSettings(quality="formula"))
    rows.setdefault("formula", []).append(score(display(f0, shot.info.irradiance_scale), gts)["psnr"])
    for s in scales:
        SCALE[0] = s
        fr, secs = render_timed(r, shot, RenderSettings(quality="residual", residual_pixels=0))  # the scale is this probe's
        sc = score(display(fr, shot.info.irradiance_scale), gts)
        rows.setdefault(f"s{s}", []).append(sc["psnr"])
        rows.setdefault(f"s{s}_sec", []).append(secs / shot.num_frames)
        print(sd.name, shot.size, f"s={s}", {k: round(v, 3) if v else v for k, v in sc.items()}, f"{secs/shot.num_frames:.2f} s/f", flush=True)
    print(sd.name, "formula", round(rows["formula"][-1], 3), flush=True)
print(json.dumps({k: round(float(np.mean(v)), 3) for k, v in rows.items()}))
