"""The keyframe bench's tables, written from its result JSON (never by hand): accuracy per method and N on the frames
between, and the whole cost of a frame beside Cycles on every frame.

    python -m bench.keyframes_report [--json bench/results/keyframes/keyframes.json] [--check]

Cost per frame, in CPU seconds of the 2-core machine that rendered the clips (wall seconds depend on what else ran):
a keyframe's path trace / N + a G-buffer frame (the add-on's keyframe export, `gbuffer_cost.json`) x (N - 1) / N +
the fill's seconds x (N - 1) / N. Cycles rows are the same renderer at 1, 2, 4 samples + OIDN on every frame, and
at the keyframes' samples on every frame. "Cycles at the same time" reads Cycles' PSNR off its own curve (linear
in log seconds between its points) at the method's cost: where the method scores above it, Cycles needs more time
to reach that PSNR.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results" / "keyframes"
LABELS = {"hold": "hold the nearest keyframe", "rife": "RIFE (colour only)", "classical": "classical fill (depth + camera)",
          "classical_flow": "classical fill by G-buffer flow (no depth)", "learned": "learned fill (tier 1)",
          "diffusion": "diffusion (tier 2), keyframes as references"}


def _mean(vals: list[float]) -> float:
    return float(np.mean(vals)) if vals else math.nan


def cycles_curve(doc: dict) -> list[tuple[float, float, str]]:
    """[(CPU seconds per frame, PSNR, label)] of Cycles on every frame, averaged over the clips, cheapest first."""
    by: dict[int, list[tuple[float, float]]] = {}
    for c in doc["clips"]:
        for r in c["cycles"]:
            by.setdefault(r["samples"], []).append((r["cpu_seconds_per_frame"], r["psnr"]))
    pts = [(_mean([a for a, _ in v]), _mean([b for _, b in v]), f"Cycles {s} spp + OIDN, every frame") for s, v in by.items()]
    keys = [c["keyframes"] for c in doc["clips"]]
    pts.append((_mean([k["cpu_seconds_per_frame"] for k in keys]), _mean([k["psnr_vs_truth"] for k in keys]),
                f"Cycles {keys[0]['samples']} spp + OIDN, every frame (the keyframes' samples)"))
    return sorted(pts)


def cycles_at(curve: list[tuple[float, float, str]], seconds: float) -> float | None:
    """Cycles' PSNR at `seconds` per frame, interpolated in log time on its curve; None outside it."""
    xs = [math.log(s) for s, _, _ in curve]
    if not curve or seconds < curve[0][0] or seconds > curve[-1][0]:
        return None
    return float(np.interp(math.log(seconds), xs, [p for _, p, _ in curve]))


def gbuffer_cpu(doc: dict) -> float:
    return float(doc["gbuffer_cost"]["headline"]["cpu_seconds_per_frame"])


def table(doc: dict) -> list[str]:
    clips = doc["clips"]
    curve = cycles_curve(doc)
    gb = gbuffer_cpu(doc)
    key_cpu = _mean([c["keyframes"]["cpu_seconds_per_frame"] for c in clips])
    every = sorted({r["every"] for c in clips for r in c["rows"]})
    methods = [m for m in LABELS if any(r["method"] == m for c in clips for r in c["rows"])]
    names = ", ".join(c["rows"][0]["clip"] for c in clips)
    out = [f"{len(clips)} test clip{'s' if len(clips) != 1 else ''} ({names}), {clips[0]['frames']} frames at {doc['size']}; "
           f"keyframes {clips[0]['keyframes']['samples']} spp + OIDN, truth {clips[0]['truth']['samples']} spp + OIDN with another "
           f"seed; the keyframes themselves score {_mean([c['keyframes']['psnr_vs_truth'] for c in clips]):.2f} dB against it "
           "(the ceiling of any fill)" + (f", TC {_mean([c['keyframes']['tc'] for c in clips]):.3f}" if "tc" in clips[0]["keyframes"] else "")
           + ".", "",
           "| N | method | PSNR between↑ | worst frame↑ | SSIM↑ | TC↓ (1 = the truth's) | CPU s/frame, all in↓ | Cycles at the same time |",
           "|---|---|---|---|---|---|---|---|"]
    for n in every:
        for m in methods:
            rows = [r for c in clips for r in c["rows"] if r["every"] == n and r["method"] == m]
            fill = _mean([r["fill_seconds"] for r in rows])
            cost = key_cpu / n + (gb + fill) * (n - 1) / n
            at = cycles_at(curve, cost)
            out.append(f"| {n} | {LABELS[m]} | {_mean([r['psnr'] for r in rows]):.2f} | {min(r['psnr_min'] for r in rows):.2f} | "
                       f"{_mean([r['ssim'] for r in rows]):.4f} | {_mean([r['tc'] for r in rows]):.3f} | {cost:.2f} | "
                       f"{'—' if at is None else f'{at:.2f}'} |")
    out += ["", "| Cycles on every frame | PSNR↑ | CPU s/frame↓ |", "|---|---|---|"]
    out += [f"| {label} | {p:.2f} | {s:.2f} |" for s, p, label in curve]
    n8 = key_cpu / 8 + gb * 7 / 8
    out += ["", f"At N = 8 a frame costs {n8:.2f} CPU s before the fill (keyframe {key_cpu:.2f} / 8 + G-buffer {gb:.2f} × 7/8): "
            f"{n8 / key_cpu:.2f} of Cycles at the keyframes' samples on every frame. G-buffer frame: {gb:.2f} CPU s "
            f"({doc['gbuffer_cost']['headline']['wall_seconds_per_frame']:.2f} s wall, load average "
            f"{_load(doc['gbuffer_cost']['headline'].get('load_average'))} on {doc['gbuffer_cost']['headline'].get('threads', 2)} threads)."]
    return out


def _load(avg: list[float] | None) -> str:
    """The load average (1 min) a G-buffer run recorded, 'not recorded' where it has none."""
    return f"{avg[0]:.1f}" if avg else "not recorded"


def render(doc: dict, source: str = "keyframes.json") -> str:
    head = [f"<!-- generated by python -m bench.keyframes_report from {source}: do not edit -->",
            f"# Path-traced keyframes: the frames between, beside hold, RIFE and Cycles ({doc['size']})", "",
            f"Command: `{doc['command']}`. Machine: {doc.get('machine', {}).get('label', 'the 2-core CPU VM')}.", ""]
    return "\n".join(head + table(doc)) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, default=RESULTS / "keyframes.json")
    ap.add_argument("--check", action="store_true", help="fail when the Markdown beside the JSON is not what it would write")
    args = ap.parse_args(argv)
    doc = json.loads(args.json.read_text())
    text = render(doc, args.json.name)
    md = args.json.with_suffix(".md")
    if args.check:
        if not md.is_file() or md.read_text() != text:
            print(f"{md}: out of date (python -m bench.keyframes_report --json {args.json})", file=sys.stderr)
            return 1
        return 0
    md.write_text(text)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
