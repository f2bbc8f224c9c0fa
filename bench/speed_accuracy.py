"""Speed vs accuracy of the sampler presets (paper Tab. acceleration): seconds per frame and PSNR/SSIM/TC of DDIM-20, DDIM-4
and LCM-2 (when distilled weights exist) on held-out rooms, beside the classical shading baseline; JSON + PNG chart.

    python -m bench.speed_accuracy --data DATA [--weights RUN_OR_DIR] [--lcm-weights LCM_RUN] [--rooms 2] [--frames 17]
        [--size WxH] [--device cuda] [--out bench/results/speed_accuracy/speed_accuracy.json]

Unlike bench.render (speed only, untrained weights), accuracy needs trained weights: this
renders the held-out shots with `x2video.eval` (same ground truth, metrics and classical
baseline as `x2video eval`). The editor's chart (x2video_app/charts.py) reads every JSON under
bench/results/ and plots each dict holding "name", "seconds_per_frame" and "psnr"; the
shape written here:
    {"format": "x2video-speed-accuracy", "command", "machine", "weights", "data",
     "rows": [{"name", "sampler", "steps", "seconds_per_frame", "psnr", "ssim", "tc", "fid", "frames"}],
     "unavailable": [{"preset", "reason"}]}
The last row is the classical baseline ("classical shading", sampler "none"). The PNG is
drawn with matplotlib when installed, else with pyqtgraph's exporter offscreen.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from bench.common import add_render_arguments, load_models, result_header, results_path, run_measure, settings
from x2video.io.atomic import atomic_path

RESULTS = results_path("speed_accuracy")
#: (sampler, steps, add the shading detail); the no-detail row is measured for residual-prior models only
PRESETS = [("ddim", 20, True), ("ddim", 4, True), ("lcm", 2, True), ("ddim", 20, False)]


def measure(args: argparse.Namespace) -> dict:
    from x2video.eval.baseline import classical_frames
    from x2video.eval.data import load_eval_shots
    from x2video.eval.runner import MISSING_LCM, render_shot, warm_up
    from x2video.eval.scoring import Scorer
    from x2video.render.renderer import Renderer

    models, _, size, size_note = load_models(args)
    shots = load_eval_shots(args.data, args.split, args.rooms, args.frames, size)
    scorer = Scorer(shots, fid=args.fid, tc=True)
    tag = " (untrained)" if args.untrained else ""
    rows, unavailable = [], []
    for sampler, steps, detail in PRESETS:
        model = models.video if sampler == "ddim" else models.lcm
        name = f"{sampler.upper()}-{steps}{tag}" + ("" if detail else ", no detail")
        if model is None:
            unavailable.append({"preset": name, "reason": MISSING_LCM})
            continue
        if not detail and not model.residual_prior:
            continue  # the same render as with detail
        renderer = Renderer(model)
        warm_up(renderer, shots[0], sampler)  # untimed: first-call costs stay out of the first preset
        renderer.cache.clear()  # every preset pays its own encoding, as in `x2video eval`
        chosen = settings(args, sampler=sampler, steps=steps, detail=detail)
        preds, secs = {}, {}
        for s in shots:
            preds[s.name], secs[s.name] = render_shot(renderer, s, None, chosen)
            print(f"{name}: {s.name} {secs[s.name] / s.num_frames:.3f} s/frame", file=sys.stderr)
        m = scorer.score(preds, secs)
        rows.append({"name": name, "sampler": sampler, "steps": steps, "detail": detail,
                     **{k: m[k] for k in ("seconds_per_frame", "psnr", "ssim", "tc", "fid", "frames")}})
    frames, secs = {}, {}
    for s in shots:
        frames[s.name], secs[s.name] = classical_frames(s.shot, None)
    m = scorer.score(frames, secs)
    rows.append({"name": "classical shading", "sampler": "none", "steps": 0,
                 **{k: m[k] for k in ("seconds_per_frame", "psnr", "ssim", "tc", "fid", "frames")}})
    head = result_header("speed-accuracy", "speed_accuracy", args, models, shots, size)
    head["data"]["size_note"] = size_note
    return {
        **head,
        "rows": rows,
        "unavailable": unavailable,
    }


def draw_chart(result: dict, path: Path) -> Path:
    """Seconds per frame (x, log) vs PSNR (y), one labelled point per row; matplotlib, else pyqtgraph offscreen."""
    from x2video.eval.machine import machine_label
    from x2video.eval.report import labels_below

    pts = [(r["name"], r["seconds_per_frame"], r["psnr"]) for r in result["rows"] if r.get("psnr") is not None and r.get("seconds_per_frame")]
    if not pts:
        raise ValueError("speed/accuracy chart: no row has both seconds per frame and PSNR")
    title = f"speed vs accuracy: {machine_label(result['machine'])}"
    below = labels_below(pts)
    with atomic_path(path) as tmp:
        _draw(pts, below, title, tmp)
    return path


def _draw(pts: list, below: set, title: str, tmp: Path) -> None:
    """The chart into the file `tmp`."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
        for i, (name, x, y) in enumerate(pts):
            ax.scatter([x], [y], marker="s" if name == "classical shading" else "o")
            ax.annotate(name, (x, y), textcoords="offset points", xytext=(5, -12 if i in below else 5), fontsize=8)
        ax.set_xscale("log")
        ax.set_xlabel("seconds per frame (log)")
        ax.set_ylabel("PSNR (dB)")
        ax.set_title(title, fontsize=8)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(tmp)
        plt.close(fig)
    except ImportError:
        os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
        import pyqtgraph as pg
        import pyqtgraph.exporters
        from PySide6.QtWidgets import QApplication

        app = QApplication.instance() or QApplication([])
        pg.setConfigOptions(background="w", foreground="k", antialias=True)
        plot = pg.PlotWidget(title=title)
        plot.resize(720, 480)
        plot.setLogMode(x=True, y=False)
        plot.setLabel("bottom", "seconds per frame (log)")
        plot.setLabel("left", "PSNR (dB)")
        import math

        for i, (name, x, y) in enumerate(pts):
            brush = (220, 120, 40) if name == "classical shading" else (40, 110, 220)
            plot.addItem(pg.ScatterPlotItem(x=[math.log10(x)], y=[y], size=10, brush=brush, symbol="s" if name == "classical shading" else "o"))
            label = pg.TextItem(name, color=(20, 20, 20), anchor=(0, 0) if i in below else (0, 1))
            label.setPos(math.log10(x), y)
            plot.addItem(label)
        xs = [math.log10(x) for _, x, _ in pts]
        lo, hi = min(xs) - 0.15, max(xs) + 0.9  # room for the right-most point's label
        plot.setXRange(lo, hi, padding=0)
        # label 1-2-5 steps only: pyqtgraph's log axis labels every minor tick and they overlap
        ticks = [(math.log10(m * 10.0**e), f"{m * 10.0**e:g}") for e in range(-4, 4) for m in (1, 2, 5)]
        plot.getAxis("bottom").setTicks([[t for t in ticks if lo <= t[0] <= hi], []])
        app.processEvents()
        exporter = pyqtgraph.exporters.ImageExporter(plot.plotItem)
        exporter.parameters()["width"] = 720
        exporter.export(str(tmp))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_render_arguments(p)
    p.add_argument("--untrained", action="store_true", help="untrained tiny weights (smoke test; names get '(untrained)')")
    p.add_argument("--fid", action="store_true", help="also compute FID (slow on a CPU)")
    p.add_argument("--out", type=Path, default=RESULTS, help=f"JSON path (PNG beside it; default {RESULTS})")
    args = p.parse_args(argv)
    result = run_measure(args, measure)
    png = draw_chart(result, args.out.with_suffix(".png"))
    for r in result["rows"]:
        print(f"{r['name']:>24}: {r['seconds_per_frame']:.3f} s/frame, PSNR {r['psnr']:.2f} dB, SSIM {r['ssim']:.4f}, TC {r['tc']}")
    for u in result["unavailable"]:
        print(f"{u['preset']:>24}: n/a ({u['reason']})")
    print(f"wrote {args.out} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
