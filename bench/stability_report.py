"""docs/STABILITY.md and its plots from bench/stability.py's results (plots drawn with OpenCV: no matplotlib)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from x2video.tiers.registry import DIFFUSION, FORMULA, RESIDUAL  # the methods' rows and what the notes say of each tier

COLOURS = {FORMULA: (60, 60, 60), RESIDUAL: (0, 150, 0), "auto": (200, 120, 0), DIFFUSION: (30, 30, 220)}  # BGR
METHODS = (FORMULA, RESIDUAL, "auto", DIFFUSION)
EXTRA_COLOURS = [(0, 150, 0), (150, 0, 150), (0, 150, 150), (120, 120, 0)]


# ------------------------------------------------------------------------------------------------ plots
def _canvas(w: int = 720, h: int = 420) -> np.ndarray:
    return np.full((h, w, 3), 255, np.uint8)


def _text(img: np.ndarray, s: str, xy: tuple[int, int], scale: float = 0.45, colour=(0, 0, 0), thick: int = 1) -> None:
    import cv2

    cv2.putText(img, s, xy, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thick, cv2.LINE_AA)


def _nice(v: float) -> str:
    return f"{v:.0f}" if abs(v) >= 10 or v == 0 else f"{v:.2g}"


def line_plot(path: Path, series: dict[str, list[tuple[float, float]]], title: str, xlabel: str, ylabel: str, logx: bool = False,
              logy: bool = False) -> None:
    """One line (with dots) per series; axes from the data; log axes on request."""
    import cv2

    img = _canvas()
    L, R, T, B = 70, 150, 40, 50
    W, H = img.shape[1] - L - R, img.shape[0] - T - B
    pts = [(x, y) for s in series.values() for x, y in s if y is not None and math.isfinite(y) and (not logx or x > 0) and (not logy or y > 0)]
    if not pts:
        return
    fx = (lambda v: math.log10(v)) if logx else (lambda v: v)
    fy = (lambda v: math.log10(v)) if logy else (lambda v: v)
    xs, ys = [fx(p[0]) for p in pts], [fy(p[1]) for p in pts]
    x0, x1 = min(xs), max(xs) + (1e-9 if max(xs) == min(xs) else 0)
    y0, y1 = min(ys), max(ys)
    pad = 0.08 * (y1 - y0 or 1.0)
    y0, y1 = y0 - pad, y1 + pad

    def px(x: float, y: float) -> tuple[int, int]:
        return int(L + (fx(x) - x0) / (x1 - x0 or 1) * W), int(T + H - (fy(y) - y0) / (y1 - y0) * H)

    cv2.rectangle(img, (L, T), (L + W, T + H), (0, 0, 0), 1)
    for k in range(5):
        yv = y0 + (y1 - y0) * k / 4
        yy = int(T + H - k / 4 * H)
        cv2.line(img, (L - 4, yy), (L + W, yy), (225, 225, 225), 1)
        _text(img, _nice(10 ** yv if logy else yv), (5, yy + 4), 0.4)
        xv = x0 + (x1 - x0) * k / 4
        xx = int(L + k / 4 * W)
        _text(img, _nice(10 ** xv if logx else xv), (xx - 12, T + H + 18), 0.4)
    _text(img, title, (L, 25), 0.55, thick=1)
    _text(img, xlabel, (L + W // 2 - 40, T + H + 40), 0.45)
    _text(img, ylabel, (5, T - 8), 0.4)
    for i, (name, s) in enumerate(series.items()):
        col = COLOURS.get(name.split()[0], EXTRA_COLOURS[i % len(EXTRA_COLOURS)])
        good = [(x, y) for x, y in s if y is not None and math.isfinite(y) and (not logx or x > 0) and (not logy or y > 0)]
        for a, b in zip(good, good[1:]):
            cv2.line(img, px(*a), px(*b), col, 2, cv2.LINE_AA)
        for p in good:
            cv2.circle(img, px(*p), 3, col, -1, cv2.LINE_AA)
        _text(img, name, (L + W + 10, T + 20 + 20 * i), 0.45, col, 1)
    if len(series) > 1:
        _text(img, "(lines may overlap)", (L + W + 10, T + 20 + 20 * len(series)), 0.38, (120, 120, 120))
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def bar_plot(path: Path, groups: list[str], series: dict[str, list[float | None]], title: str, ylabel: str,
             crashed: dict[str, list[bool]] | None = None) -> None:
    """Vertical grouped bars, one group per case (labels rotated as short text), one bar per series; an X marks a crash."""
    import cv2

    gw = max(24, 14 * len(series) + 8)
    img = _canvas(max(720, 90 + gw * len(groups) + 130), 460)
    L, T, B = 70, 40, 110
    H = img.shape[0] - T - B
    vals = [v for s in series.values() for v in s if v is not None and math.isfinite(v)]
    if not vals:
        return
    y0, y1 = min(0.0, min(vals)), max(vals) * 1.05 or 1.0

    def py(v: float) -> int:
        return int(T + H - (v - y0) / (y1 - y0) * H)

    Wd = gw * len(groups)
    cv2.rectangle(img, (L, T), (L + Wd, T + H), (0, 0, 0), 1)
    for k in range(5):
        v = y0 + (y1 - y0) * k / 4
        cv2.line(img, (L - 4, py(v)), (L + Wd, py(v)), (225, 225, 225), 1)
        _text(img, _nice(v), (5, py(v) + 4), 0.4)
    _text(img, title, (L, 25), 0.55)
    _text(img, ylabel, (5, T - 8), 0.4)
    for g, label in enumerate(groups):
        gx = L + g * gw + 4
        for i, (name, s) in enumerate(series.items()):
            col = COLOURS.get(name, EXTRA_COLOURS[i % len(EXTRA_COLOURS)])
            x = gx + 14 * i
            v = s[g]
            if crashed and crashed[name][g]:
                cv2.line(img, (x, T + H - 12), (x + 10, T + H - 2), (0, 0, 255), 2)
                cv2.line(img, (x, T + H - 2), (x + 10, T + H - 12), (0, 0, 255), 2)
            elif v is not None and math.isfinite(v):
                cv2.rectangle(img, (x, py(v)), (x + 10, py(max(y0, 0.0))), col, -1)
        # the label, written downwards one short line per 6 characters
        for k in range(0, min(len(label), 24), 6):
            _text(img, label[k:k + 6], (gx, T + H + 14 + 12 * (k // 6)), 0.33)
    for i, name in enumerate(series):
        _text(img, name, (L + Wd + 10, T + 20 + 20 * i), 0.45, COLOURS.get(name, EXTRA_COLOURS[i % len(EXTRA_COLOURS)]))
    _text(img, "X = crashed", (L + Wd + 10, T + 20 + 20 * len(series)), 0.4, (0, 0, 255))
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


# ------------------------------------------------------------------------------------------------ tables
def _f(v: Any, nd: int = 2) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def _cell_text(c: dict | None) -> str:
    if c is None:
        return ""
    if c.get("skipped"):
        return "skipped"
    if c["crashed"]:
        return f"**crash** ({c['error'][:70]})"
    rss = f"{_f(c.get('peak_rss_mb'), 0)} MB (+{_f(c.get('peak_rss_above_start_mb'), 0)})"
    parts = [f"{_f(c.get('psnr'))} dB", f"TC {_f(c.get('tc'))}", f"{_f(c.get('seconds'), 1)} s", rss]
    if c.get("nonfinite_frac"):
        parts.append(f"**{100 * c['nonfinite_frac']:.0f}% NaN/Inf**")
    if c.get("tier") and c["method"] == "auto":
        parts.append(f"tier {c['tier']}")
    if c.get("delta_e") is not None:
        parts.append(f"dE {_f(c['delta_e'])} ({_f(c['delta_e_first'])} -> {_f(c['delta_e_last'])})")
    if c.get("psnr_by_class"):
        parts.append(", ".join(f"{k} {_f(v, 1)}" for k, v in c["psnr_by_class"].items() if v is not None))
    return " / ".join(parts)


def family_table(cells: list[dict], family: str, methods: list[str]) -> list[str]:
    rows: dict[str, dict[str, dict]] = {}
    for c in cells:
        if c["family"] == family:
            rows.setdefault(c["name"], {})[c["method"]] = c
    if not rows:
        return []
    out = ["| case | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for name, by in rows.items():
        out.append(f"| {name} | " + " | ".join(_cell_text(by.get(m)) for m in methods) + " |")
    return out


# ------------------------------------------------------------------------------------------------ what the product does
def product_note(f: dict) -> str:
    """What the product does where a method fails (by family, case and method)."""
    fam, name, method, kind = f["family"], f["name"], f["method"], f["failure"]
    below = "below the formula" in kind
    files = ("shots read from files never get here: every loader zeroes NaN/Inf with a warning and clamps each channel to its "
             "range, normals normalised (x2video.io.convention.sanitize); only in-memory shots (Python API) reach the renderer as given")
    if kind == "crash":
        return "the render fails with RenderFailed carrying the message; nothing is written (the editor shows it in the log)"
    if fam == "channels" and name.count("+") == 4:
        fam = "length"  # every channel kept: the plain case
    if fam == "channels" and method == RESIDUAL:
        return ("tier 1 forced with a channel missing: the net reads the missing channel as zeros and was never trained so; "
                "'auto' never does this (missing normal, roughness or metallic alone: the formula; anything else missing: the sampler), "
                "only quality 'residual' forced by hand")
    if fam == "channels" and method == FORMULA:
        return ("the formula needs albedo and irradiance; without either it is black. 'auto' runs the formula only where both "
                "are present; a missing albedo or irradiance sends it to the diffusion sampler (x2video.tiers.registry.choose_tier; the log says which)")
    if fam == "channels" and "alb" in name.split("+") and "irr" in name.split("+"):
        return ("the sampler, given albedo and irradiance but not every other channel, rendered below the formula on all 7 such "
                "subsets of these rooms; 'auto' renders the formula when only normal, roughness or metallic are missing "
                "(x2video.tiers.registry.FORMULA_IGNORES), decided on validation rooms, where the sampler and tier 1 are above "
                "the formula on 6 of the 7 but 3-4 dB under it without roughness (bench/results/stability/stability_v3val6.json); "
                "the sampler runs there only when forced")
    if fam == "channels":
        return "'auto' runs the sampler for a dropped channel; what it generates is the model's guess, scored against one truth"
    if fam == "masks" and method == FORMULA:
        return ("the formula leaves A|M|R regions black (nothing to multiply); 'auto' generates them with the sampler and keeps "
                "tier 1 around them over a feathered seam")
    if fam == "hostile" and name == "negative_roughness":
        return ("clamped to [0, 1] (the loaders; `to_vae_range` and tier 1's features in memory): roughness -0.5 is roughness 0, "
                "a mirror-like scene that tier 1 and the sampler render as such; the formula ignores roughness, so only their scores "
                "move. 'auto' keeps the formula on such a frame (x2video.model.plausible.out_of_range: a unit channel outside [0, 1])")
    if fam == "foreign" and method == RESIDUAL:
        return ("tier 1 forced on irradiance at another renderer's level, left as the file wrote it: 'auto' keeps the formula "
                "where the level lies outside the ones tier 1 was trained on and where the irradiance is clipped at a file's "
                "ceiling (x2video.model.plausible.out_of_range)")
    if fam == "size" and method == RESIDUAL:
        from x2video.model.plausible import MIN_SIDE

        return ("tier 1 forced on frames of a few pixels, whose global context is a cell or two: 'auto' keeps the formula "
                f"under {MIN_SIDE} pixels a side (x2video.model.plausible.MIN_SIDE)")
    if fam == "hostile" and name == "zero_normals" and method == RESIDUAL:
        return ("zero normals mean 'no geometry here' (a window) to tier 1; it keeps the formula wherever the channels say "
                "nothing of the light (x2video.model.residual.unseen_light), so zero normals give the formula's frames")
    if fam == "hostile" and name.startswith("albedo_"):
        return f"rendered as given: albedo {name[-1]} everywhere is a different scene from the truth it is scored on. {files}"
    if fam == "hostile":
        return f"{files}. In memory: tiers 0/1 and the sampler count NaN/Inf as 0 (core fixes); out-of-range values go through as given"
    if below and method == DIFFUSION and fam in ("channels", "masks", "length", "size", "noise", "limits"):
        return ("'auto' does not run the sampler when every channel is present (tier 1 renders, or the formula where a net's "
                "record does not trust it); the sampler is there only when "
                "forced (quality 'diffusion') or for what must be generated. Its gap to the formula here is the tiny shipped "
                "model at preset fast (LCM-2), largest at sizes whose latent is a few pixels")
    if fam == "foreign" and method != RESIDUAL:
        return ("auto keeps the formula wherever tier 1's correction of it is larger than the bounds chosen on validation rooms, "
                "or its input is not of the kind it was trained on (x2video.model.plausible); a forced 'residual' renders the "
                "net as it is, and the sampler only when forced")
    if fam == "noise":
        return ("channels are used as given: a noisy irradiance makes a noisy frame in every tier; denoise the passes first "
                "(Cycles' denoiser, OIDN)")
    if fam == "limits":
        return ("windows, mirrors and metals are what the formula cannot do (no glossy term, no sky) and what tier 1 is trained "
                "to add; the per-class PSNR says how far each tier gets")
    return ""


def observations(cells: list[dict]) -> list[str]:
    """Sentences the numbers support (computed, so they follow the results)."""
    get = {(c["family"], c["name"], c["method"]): c for c in cells if not c.get("skipped") and not c["crashed"]}
    out = []
    a, b = get.get(("masks", "1", "auto")), get.get(("masks", "1+prompts", "auto"))
    f = get.get(("masks", "1", FORMULA))
    if a and f and a.get("psnr_by_class") and f.get("psnr_by_class") and "+" not in str(a.get("tier", "+")):
        out.append(f"- One masked-out object sends 'auto' to the sampler for the whole frame (tier {a.get('tier')}): tier 1 is not "
                   "trusted, so there is no regional composite around the mask. Outside the mask PSNR is "
                   f"{a['psnr_by_class']['outside']:.1f} dB, where the formula gives {f['psnr_by_class']['outside']:.1f} dB; a composite "
                   "over the formula (tier 0 around the generated region) would keep the formula's quality there.")
    elif a and b and a.get("psnr_by_class") and b.get("psnr_by_class") and "+" in str(b.get("tier")):
        out.append(f"- A local prompt on a masked object takes the regional path too (tier {b.get('tier')}: the sampler's pixels "
                   f"inside the mask, tier 1 around it): outside the mask PSNR is {b['psnr_by_class']['outside']:.1f} dB with the "
                   f"prompt and {a['psnr_by_class']['outside']:.1f} dB without; inside {b['psnr_by_class']['inside']:.1f} and "
                   f"{a['psnr_by_class']['inside']:.1f} dB.")
    elif a and b and a.get("psnr_by_class") and b.get("psnr_by_class"):
        out.append(f"- A local prompt sends 'auto' to the sampler for the whole frame (tier {b.get('tier')}), not only inside its "
                   f"mask: outside one masked object PSNR is {a['psnr_by_class']['outside']:.1f} dB with the regional composite "
                   f"(tier {a.get('tier')}) and {b['psnr_by_class']['outside']:.1f} dB with a local prompt on the same mask. "
                   "Letting local prompts on A|M|R-masked regions take the regional path would keep tier 1 outside them.")
    part = [(c, get.get(("channels", c["name"], FORMULA))) for c in cells if c["family"] == "channels" and c["method"] == "auto"
            and {"alb", "irr"} <= set(c["name"].split("+")) and c["name"].count("+") < 4 and not c["crashed"] and not c.get("skipped")]
    part = [(c, f) for c, f in part if f and c.get("psnr") is not None and f.get("psnr") is not None]
    if part:
        lo, hi = min(c["psnr"] for c, _ in part), max(c["psnr"] for c, _ in part)
        tiers_run = sorted({str(c.get("tier")) for c, _ in part})
        diff = [d["psnr"] for c, _ in part if (d := get.get(("channels", c["name"], DIFFUSION))) and d.get("psnr") is not None]
        out.append(f"- With albedo and irradiance kept but some of normal/roughness/metallic dropped ({len(part)} subsets), 'auto' "
                   f"runs {' / '.join(tiers_run)}: {lo:.1f} to {hi:.1f} dB, where the formula gives {part[0][1]['psnr']:.1f} dB"
                   + (f" and the sampler {min(diff):.1f} to {max(diff):.1f} dB." if diff else "."))
    big = [c for c in cells if c["family"] == "size" and c.get("params", {}).get("size") == [1920, 1080] and not c.get("skipped")
           and not c["crashed"] and (c["method"] == RESIDUAL or (c["method"] == "auto" and c.get("tier") == RESIDUAL))]
    if big:
        c = big[0]
        out.append(f"- Tier 1 at 1920x1080 ({c['frames']} frames, batches of 4): {c['seconds'] / c['frames']:.1f} s a frame and "
                   f"{c['peak_rss_above_start_mb'] / 1024:.1f} GB above the process's start (peak {c['peak_rss_mb'] / 1024:.1f} GB); "
                   "frames above `residual.MAX_PIXELS` run in tiles (`residual.apply_tiled`), so memory stays bounded as frames grow.")
    lens = sorted((c for c in cells if c["family"] == "length" and c["method"] == FORMULA and c.get("delta_e") is not None),
                  key=lambda c: c["frames"])
    if lens:
        c = lens[-1]
        out.append(f"- No drift in tiers 0/1: on {c['frames']} frames the formula's mean Lab dE is {c['delta_e_first']:.2f} over the "
                   f"first tenth and {c['delta_e_last']:.2f} over the last (per-frame tiers cannot drift); peak RSS stays "
                   f"{c['peak_rss_above_start_mb']:.0f} MB above the start (frames are streamed, not held).")
    d = sorted((c for c in cells if c["family"] == "length" and c["method"] == DIFFUSION and c.get("delta_e") is not None),
               key=lambda c: c["frames"])
    if d:
        c = d[-1]
        out.append(f"- The sampler on {c['frames']} frames: dE {c['delta_e_first']:.2f} over the first tenth, {c['delta_e_last']:.2f} "
                   "over the last (longer shots were skipped for the sampler on this CPU).")
    fams = ("length", "size", "noise", "limits")
    pairs = [(c, get.get((c["family"], c["name"], FORMULA))) for c in cells if c["method"] == RESIDUAL and c["family"] in fams]
    diffs = [c["psnr"] - f["psnr"] for c, f in pairs if f and c.get("psnr") is not None and f.get("psnr") is not None]
    if diffs:
        out.append(f"- Tier 1 forced, against the formula on the same case with every channel present ({len(diffs)} cases: "
                   f"{', '.join(fams)}): median {float(np.median(diffs)):+.2f} dB, from {min(diffs):+.2f} to {max(diffs):+.2f} dB.")
    lim = [c for c in cells if c["family"] == "limits" and c.get("pixel_share", {}).get("window")]
    if not lim:
        out.append("- No window pixels (normal == 0) in the shots run: the window class is unmeasured here.")
    return out or ["- none"]


def provenance(cells: list[dict], run: int) -> str:
    """Which methods and families of a merged report come from run number `run`."""
    kept: dict[str, dict[str, int]] = {}
    for c in cells:
        if c.get("run") == run:
            fams = kept.setdefault(c["method"], {})
            fams[c["family"]] = fams.get(c["family"], 0) + 1
    if not kept:
        return "none (every cell replaced by a later run)"
    return "; ".join(f"{m}: " + ", ".join(f"{f} ({n})" for f, n in fams.items()) for m, fams in kept.items())


def tier1_note(model: dict) -> str:
    """What the 'residual' and 'auto' columns show, from the run's model record."""
    net = str(model.get("residual_net", ""))
    if net.startswith("randomly"):
        return ("tier 1 is a randomly initialised net (equal to the formula: its output layer starts at zero), so 'residual' and "
                "'auto' where it picks tier 1 equal the formula")
    if model.get("auto_uses_tier1", True):
        return f"tier 1 is the {net or 'loaded'} net, and 'auto' runs it wherever nothing must be generated"
    return (f"tier 1 is the {net or 'loaded'} net; its record (residual.json 'auto': false, it measured below the formula on the "
            "outside scenes) keeps 'auto' on the formula wherever nothing must be generated, so the 'residual' column (quality "
            "'residual' forced) is where tier 1 shows")


def faults_section(md: Path) -> list[str]:
    """The hand-written faults table (docs/stability/faults.md, issue 44: what the product does on a full disk, a crash,
    files changing under a render, bad flags), which no bench run measures, copied in as it is."""
    src = md.parent / "stability" / "faults.md"
    return ["", *src.read_text(encoding="utf-8").rstrip().splitlines()] if src.is_file() else []


def write_report(out: dict, md: Path, figs: Path) -> None:
    cells = out["cells"]
    methods = [m for m in METHODS if any(c["method"] == m for c in cells)]
    figs.mkdir(parents=True, exist_ok=True)
    suffix = "_quick" if out.get("quick") else ""
    images: list[tuple[str, str]] = []

    def by(family: str) -> dict[str, dict[str, dict]]:
        d: dict[str, dict[str, dict]] = {}
        for c in cells:
            if c["family"] == family:
                d.setdefault(c["name"], {})[c["method"]] = c
        return d

    def ok(c: dict | None, key: str) -> float | None:
        return None if c is None or c.get("skipped") or c["crashed"] else c.get(key)

    ch = by("channels")
    if ch:
        names = list(ch)
        p = figs / f"channels{suffix}.png"
        bar_plot(p, names, {m: [ok(ch[n].get(m), "psnr") for n in names] for m in methods}, "PSNR by channels kept (dB)", "dB",
                 {m: [bool(ch[n].get(m, {}).get("crashed")) for n in names] for m in methods})
        images.append(("Channels kept", p.name))
    ln = by("length")
    if ln:
        lengths = sorted(ln, key=lambda n: int(n.rstrip("f")))
        p = figs / f"length_rss{suffix}.png"
        line_plot(p, {m: [(int(n.rstrip("f")), ok(ln[n].get(m), "peak_rss_mb")) for n in lengths] for m in methods},
                  "peak RSS by shot length", "frames", "MB", logx=True)
        images.append(("Memory by shot length", p.name))
        series = {}
        for m in methods:
            done = [n for n in lengths if ok(ln[n].get(m), "delta_e_series")]
            if done:
                series[f"{m} {done[-1]}"] = [(t, v) for t, v in ln[done[-1]][m]["delta_e_series"]]
        p = figs / f"length_drift{suffix}.png"
        line_plot(p, series, "drift: mean Lab dE to the ground truth along the shot", "frame", "dE")
        images.append(("Drift along the longest shot each method rendered", p.name))
    sz = by("size")
    if sz:
        names = list(sz)
        px = {n: sz[n][next(iter(sz[n]))]["params"]["size"][0] * sz[n][next(iter(sz[n]))]["params"]["size"][1] for n in names}
        p = figs / f"size_seconds{suffix}.png"
        line_plot(p, {m: [(px[n], (ok(sz[n].get(m), "seconds") or 0) / max(sz[n].get(m, {}).get("frames", 1), 1) or None) for n in names]
                      for m in methods}, "seconds per frame by frame size", "pixels", "s", logx=True, logy=True)
        images.append(("Seconds per frame by size", p.name))
        p = figs / f"size_rss{suffix}.png"
        line_plot(p, {m: [(px[n], ok(sz[n].get(m), "peak_rss_mb")) for n in names] for m in methods}, "peak RSS by frame size", "pixels",
                  "MB", logx=True)
        images.append(("Memory by size", p.name))
    nz = by("noise")
    spp = [n for n in nz if n.endswith("spp")]
    if spp:
        p = figs / f"noise{suffix}.png"
        line_plot(p, {m: [(int(n[:-3]), ok(nz[n].get(m), "psnr")) for n in spp] for m in methods}, "PSNR by samples per pixel of the irradiance",
                  "spp", "dB", logx=True)
        images.append(("Noisy irradiance", p.name))
    lim = by("limits")
    if lim:
        classes = ["other", "window", "metal", "mirror"]
        series = {}
        for m in methods:
            vals = []
            for k in classes:
                sse = npx = 0.0
                for n in lim:
                    c = lim[n].get(m)
                    if c and not c.get("skipped") and not c["crashed"] and c.get("psnr_by_class", {}).get(k) is not None:
                        share = c["pixel_share"][k] * c["frames"] * c["size"][0] * c["size"][1]
                        sse += share * 10 ** (-c["psnr_by_class"][k] / 10)
                        npx += share
                vals.append(10 * math.log10(npx / sse) if npx and sse else None)
            series[m] = vals
        p = figs / f"limits{suffix}.png"
        bar_plot(p, classes, series, "PSNR per pixel class (pooled over the shots)", "dB")
        images.append(("Limitation cases", p.name))

    crashes = [c for c in cells if c["crashed"]]
    skipped = [c for c in cells if c.get("skipped")]
    lines = [
        "# Stability where methods fail",
        "",
        "*Generated by `bench/stability.py` (issue 30 item 3); do not edit by hand: rerun the bench.*",
        "",
        *(["Runs, merged in this order (a later run's cell replaces an earlier one's; `--report` merges them), and the cells "
           "each kept:", "", *[f"- `{c}`: {provenance(cells, i)}" for i, c in enumerate(out["command"].split(" ; "))], ""]
          if " ; " in out["command"] else [f"Command: `{out['command']}`  "]),
        f"Data: {out['data']} ({len(out['sources'])} shot(s)); model: {out['model'].get('weights', 'not loaded')}; tier 1: "
        f"{out['model'].get('residual_net', '-')}; {out['threads']} threads; {out['wall_seconds'] / 60:.1f} min in all.  ",
        f"Machine: {out['machine'].get('cpu', '')} {out['machine'].get('device', '')}".rstrip() + "  ",
        f"Grid: {'merged' if ' ; ' in out['command'] else ('quick (reduced)' if out['quick'] else 'full')}; {len(cells)} cells, {len(crashes)} crash(es), "
        f"{len(skipped)} skipped ({'; '.join(sorted({c['skipped'] for c in skipped})) or 'none'}).",
        "",
        out["note"] + ".",
        "",
        "Each cell: PSNR / TC / seconds / peak RSS (the process's, model included; in brackets: above the RSS at the cell's "
        "start) / the tier 'auto' ran, and per family "
        "its extra numbers. A failure is a crash, non-finite output, or a PSNR more than 3 dB under the formula's on the same case.",
        "",
        "## Summary",
        "",
        "| family | " + " | ".join(f"{m}: ok / run, crashes, NaN, median PSNR, median s" for m in methods) + " |",
        "|---|" + "---|" * len(methods),
    ]
    for fam in dict.fromkeys(c["family"] for c in cells):
        row = []
        for m in methods:
            cs = [c for c in cells if c["family"] == fam and c["method"] == m and not c.get("skipped")]
            if not cs:
                row.append("-")
                continue
            bad = {(f["family"], f["name"]) for f in out["findings"] if f["method"] == m}
            ps = [c["psnr"] for c in cs if c.get("psnr") is not None]
            ss = [c["seconds"] for c in cs if c.get("seconds") is not None]
            row.append(f"{sum((fam, c['name']) not in bad for c in cs)} / {len(cs)}, {sum(c['crashed'] for c in cs)}, "
                       f"{sum(bool(c.get('nonfinite_frac')) for c in cs)}, {_f(float(np.median(ps)) if ps else None)} dB, "
                       f"{_f(float(np.median(ss)) if ss else None, 1)} s")
        lines.append(f"| {fam} | " + " | ".join(row) + " |")
    lines += [
        "",
        "Reading it: timings are wall seconds on 2 CPU cores shared with other jobs whose load varied a lot during the runs "
        "(a 2-frame diffusion cell took from under 1 s to 30 s), so compare seconds only between neighbouring cells; "
        + tier1_note(out["model"]) + ("; in a merged report each cell is its last run's (listed above), measured with that run's data and "
                                      "the weights shipped on its day: a run before a change of weights describes the earlier "
                                      "weights (the diffusion tier's cells of runs before 2026-12-04 are the classical-prior "
                                      "model's, which that day's tier-1-prior model replaced; docs/evaluations/)"
                                      if " ; " in out["command"] else "")
        + "; peak RSS is the whole process's (the loaded model is most of it), and after a 1920x1080 tier-1 frame the "
        "process keeps about 2 GB more (ONNX Runtime's memory arena, switched off since these runs: 0.3 GB stays after such a frame now), "
        "which is why the size family runs last: read the bracketed "
        "number (above the cell's start) there.",
        "",
        "## Failures and what the product does instead",
        "",
    ]
    fnd = out["findings"]
    if not fnd:
        lines.append("None.")
    else:
        groups: dict[tuple[str, str, str], list[str]] = {}
        for f in fnd:
            below = "below the formula" in f["failure"]
            kind = "below the formula by more than 3 dB" if below else f["failure"] + (f" ({f['error'][:90]})" if f.get("error") else "")
            case = f"{f['family']} {f['name']}" + (f" ({f['failure'].split()[0]} dB)" if below else "")
            groups.setdefault((f["method"], kind, product_note(f)), []).append(case)
        lines += ["| method | failure | cases | what the product does |", "|---|---|---|---|"]
        for (method, kind, note), cases in groups.items():
            lines.append(f"| {method} | {kind} | {', '.join(cases)} | {note} |")
    lines += ["", "## Fixed in core because of this bench", "",
              "- tier 0 with every channel dropped crashed (StopIteration in `x2video.formula.formula`); it now renders black frames;",
              "- tier 1 with one NaN in the channels gave an all-NaN frame (the NaN reached the net's global context); "
              "NaN/Inf now count as 0 in `residual.features`, as the loaders make them;",
              "- the diffusion tier refused a frame with NaN/Inf (`ValueError: ... holds NaN/Inf`); it now zeroes them with a warning;",
              "- tier 1 took roughness and metallic outside [0, 1] as given (roughness -0.5: 28 dB below the formula); "
              "`residual.features` now clamps them, as the loaders and the sampler do;",
              "- the classical shading (the shading prior's latent, the residual model's detail) let NaN albedo through "
              "(NaN frames from the diffusion tier) and turned +Inf irradiance into 3.4e38 (10 dB lost); non-finite values count as 0."]
    lines += faults_section(md)
    lines += ["", "## Observations", ""]
    lines += observations(cells)
    for fam, what in (("channels", "Channel subsets (the rest dropped via Edits.dropped)"),
                      ("masks", "Masks (MaskOut A|M|R per mask; PSNR inside / outside the masks)"),
                      ("length", "Shot length (lazily looped shot; dE = mean Lab dE, first -> last tenth of the shot)"),
                      ("size", "Frame size"), ("noise", "Noisy irradiance (Cycles' sampled passes; Poisson-like at N spp)"),
                      ("hostile", "Hostile values (NaN/Inf/1e6 in a patch of the irradiance or albedo; the rest everywhere; "
                                  "PSNR against the unmodified shot's ground truth)"),
                      ("limits", "Limitation cases: PSNR per pixel class (window: normal 0; metal: metallic > 0.5; mirror: and roughness < 0.05)"),
                      ("foreign", "Foreign inputs (our shots as other tools write them, read back; PSNR after one fitted exposure per frame)")):
        t = family_table(cells, fam, methods)
        if t:
            lines += ["", f"## {what}", "", *t]
            if fam == "limits":
                lines += ["", "shotN: the Nth source shot (" + ", ".join(f"{i}: {n}" for i, n in enumerate(out["sources"])) + ")."]
    if images:
        lines += ["", "## Plots", ""]
        for title, name in images:
            lines += [f"**{title}**", "", f"![{title}](stability/{name})", ""]
    md.parent.mkdir(parents=True, exist_ok=True)
    md.write_text("\n".join(lines).rstrip() + "\n")
