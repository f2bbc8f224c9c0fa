"""Speed vs accuracy of the sampler presets (paper Tab. acceleration): seconds per frame and PSNR/SSIM/TC of DDIM-20, DDIM-4
and LCM-2 (when distilled weights exist) on held-out rooms, beside the classical shading baseline; JSON + PNG chart.

    python bench/speed_accuracy.py --data DATA [--weights RUN_OR_DIR] [--lcm-weights LCM_RUN] [--rooms 2] [--frames 17]
        [--size WxH] [--device cuda] [--out bench/results/speed_accuracy.json]

Unlike bench/render.py (speed only, untrained weights), accuracy needs trained weights: this
renders the held-out shots with `x2video.eval` (same ground truth, metrics and classical
baseline as `x2video eval`). The editor's chart (x2video_app/charts.py) reads every JSON in
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
import shlex
import sys
import time
from pathlib import Path

from x2video.cli.args import BF16_ENCODER_HELP, CHANNEL_ENCODER_HELP, MAX_LEVELS_HELP, NOISE_HELP, NOISE_SHARED_HELP, REF_DC_HELP, RESAMPLE_HELP, SEAMS_HELP, size_arg
from x2video.model.config import CHANNEL_ENCODERS, DEFAULT_CHANNEL_ENCODER

RESULTS = Path(__file__).resolve().parent / "results" / "speed_accuracy.json"
#: (sampler, steps, add the shading detail); the no-detail row is measured for residual-prior models only
PRESETS = [("ddim", 20, True), ("ddim", 4, True), ("lcm", 2, True), ("ddim", 20, False)]


def measure(args: argparse.Namespace) -> dict:
    from x2video.cli.eval import load_models, resolve_size
    from x2video.eval.baseline import classical_frames
    from x2video.eval.data import load_eval_shots
    from x2video.eval.runner import MISSING_LCM, render_shot, warm_up
    from x2video.eval.scoring import Scorer
    from x2video.sampling.events import RenderSettings
    from x2video.sampling.renderer import Renderer

    args.image_weights = None
    models, weights_dir = load_models(args, with_image=False)
    size, size_note = resolve_size(args, weights_dir, models.video.downsample)
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
        settings = RenderSettings(sampler=sampler, steps=steps, seed=args.seed, window=args.window, detail=detail,  # type: ignore[arg-type]
                                  replace_refs=args.replace_refs, seams=args.seams, max_levels=args.max_levels, noise=args.noise, noise_shared=args.noise_shared,
                                  ref_dc=args.ref_dc, resample=args.resample)
        preds, secs = {}, {}
        for s in shots:
            preds[s.name], secs[s.name] = render_shot(renderer, s, None, settings)
            print(f"{name}: {s.name} {secs[s.name] / s.num_frames:.3f} s/frame", file=sys.stderr)
        m = scorer.score(preds, secs)
        rows.append({"name": name, "sampler": sampler, "steps": steps, "detail": detail, **{k: m[k] for k in ("seconds_per_frame", "psnr", "ssim", "tc", "fid", "frames")}})
    frames, secs = {}, {}
    for s in shots:
        frames[s.name], secs[s.name] = classical_frames(s.shot, None)
    m = scorer.score(frames, secs)
    rows.append({"name": "classical shading", "sampler": "none", "steps": 0,
                 **{k: m[k] for k in ("seconds_per_frame", "psnr", "ssim", "tc", "fid", "frames")}})
    head = result_header("speed-accuracy", "speed_accuracy.py", args, models, shots, size)
    head["data"]["size_note"] = size_note
    return {
        **head,
        "rows": rows,
        "unavailable": unavailable,
    }


def result_header(kind: str, script: str, args: argparse.Namespace, models, shots: list, size: tuple[int, int],
                  argv: list[str] | None = None) -> dict:
    """The fields every bench JSON here starts with: format, the command that reproduces it (`script` in bench/,
    or a repository path; `argv`, default sys.argv[1:]), machine, weights, data."""
    from x2video.eval.machine import machine_info

    return {
        "format": f"x2video-{kind}",
        "command": shlex.join(["python", script if "/" in script else f"bench/{script}", *(sys.argv[1:] if argv is None else argv)]),
        "machine": machine_info(models.video.device),
        "weights": models.info,
        "data": {"dir": str(args.data), "split": args.split, "rooms": [s.name for s in shots], "frames": args.frames, "size": list(size)},
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
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
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
    os.replace(tmp, path)
    return path


def add_render_arguments(p: argparse.ArgumentParser) -> None:
    """Held-out data, weights, device and sampling arguments shared with bench/lcm_speedup.py."""
    p.add_argument("--data", type=Path, required=True, help="data set folder (DATA/test/room_*)")
    p.add_argument("--split", default="test")
    p.add_argument("--rooms", type=int, default=2, help="first K held-out rooms (default 2)")
    p.add_argument("--frames", type=int, default=17, help="first T frames per shot (default 17)")
    p.add_argument("--size", type=size_arg, help="WxH (default: the model's training size)")
    p.add_argument("--weights", type=Path, help="video model run or folder (default: resources/)")
    p.add_argument("--lcm-weights", type=Path, help="LCM run or folder")
    p.add_argument("--device", default=None)
    p.add_argument("--fp16", action="store_true")
    p.add_argument("--bf16-encoder", action="store_true", help=BF16_ENCODER_HELP)
    p.add_argument("--channel-encoder", choices=CHANNEL_ENCODERS, default=DEFAULT_CHANNEL_ENCODER, help=CHANNEL_ENCODER_HELP)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--window", type=int, default=5)
    from x2video.sampling.events import RenderSettings  # light (no torch); keeps the benches on the Renderer's default

    p.add_argument("--replace-refs", action=argparse.BooleanOptionalAction, default=RenderSettings.replace_refs,
                   help="hold reference frames at their noised latents between steps (default: as x2video render)")
    p.add_argument("--seams", action=argparse.BooleanOptionalAction, default=RenderSettings.seams, help=SEAMS_HELP)
    p.add_argument("--max-levels", type=int, default=RenderSettings.max_levels, help=MAX_LEVELS_HELP)
    p.add_argument("--noise", choices=("window", "frame"), default=RenderSettings.noise, help=NOISE_HELP)
    p.add_argument("--noise-shared", type=float, default=RenderSettings.noise_shared, help=NOISE_SHARED_HELP)
    p.add_argument("--ref-dc", type=float, default=RenderSettings.ref_dc, help=REF_DC_HELP)
    p.add_argument("--resample", type=int, default=RenderSettings.resample, help=RESAMPLE_HELP)
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = default)")


def run_measure(args: argparse.Namespace, measure_fn) -> dict:
    """Set torch's threads, run `measure_fn(args)`, add its wall time and write the JSON to args.out atomically."""
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    from x2video.io.atomic import write_json_atomic

    t0 = time.perf_counter()
    result = measure_fn(args)
    result["wall_seconds"] = time.perf_counter() - t0
    write_json_atomic(args.out, result)
    return result


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
