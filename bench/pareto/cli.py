"""`python -m bench.pareto`: measure, merge or replot, then write the JSON, the Markdown and the chart (see bench.pareto)."""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import bench.pareto
from bench.common import clean_json, command, results_path
from bench.pareto.chart import draw
from bench.pareto.measure import NEAR_BEST_DB, ParetoOptions, measure
from bench.pareto.merge import merge, section_of
from bench.pareto.report import markdown
from x2video.fields import add_fields, from_args
from x2video.tiers import registry as tiers

DOCS = Path(__file__).resolve().parents[2] / "docs"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.pareto", description=bench.pareto.__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_fields(ap, ParetoOptions)
    opts = from_args(ParetoOptions, ap.parse_args(argv))
    from x2video.io.atomic import write_json_atomic, write_text_atomic

    if opts.replot:
        src = Path(opts.replot)
        result = json.loads(src.read_text())
        md = results_path("pareto", src.stem, ".md") if not opts.out else Path(opts.out).with_suffix(".md")
        write_text_atomic(md, markdown(result))
        print(f"wrote {md}, {draw(result, (Path(opts.out) if opts.out else src).with_suffix('.png')) if opts.png else ''}")
        return 0

    if (opts.section or opts.from_result) and not opts.merge:
        raise SystemExit("--section and --from-result go with --merge (the result to add to)")
    if opts.merge:
        origin = Path(opts.merge)
        if not origin.is_file():
            raise SystemExit(f"--merge {origin}: no such file")
        old = json.loads(origin.read_text())
        out = Path(opts.out) if opts.out else origin
        if opts.from_result:
            result = clean_json(merge(old, json.loads(Path(opts.from_result).read_text()), opts.section, origin, command("pareto", argv)))
        else:
            if section_of(old, opts.section) is not None:
                keys = [t.strip().lower() for t in opts.methods.split(",") if t.strip()]
                opts = dataclasses.replace(opts, methods=",".join([tiers.FORMULA] + [k for k in keys if k != tiers.FORMULA]))
                print("--merge: formula is measured first (a deterministic row: it checks this run's reference against the kept rows')",
                      file=sys.stderr)
            result = clean_json(merge(old, clean_json(measure(opts, argv, lambda partial: write_json_atomic(
                out, clean_json(merge(old, clean_json(partial), opts.section, origin))))), opts.section, origin))
    else:
        out = Path(opts.out) if opts.out else DOCS / "pareto.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        result = clean_json(measure(opts, argv, lambda partial: write_json_atomic(out, clean_json(partial))))
    write_json_atomic(out, result)
    md = results_path("pareto", out.stem, ".md") if out.resolve().parent == DOCS.resolve() else out.with_suffix(".md")
    md.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(md, markdown(result))
    wrote = [out, md]
    if opts.png:
        try:
            wrote.append(draw(result, out.with_suffix(".png")))
        except ImportError:
            print("no PNG: matplotlib is not installed (pip install 'x2video-studio[bench]')", file=sys.stderr)
    for size, s in result["summary"].items():
        print(f"{size}: fastest within {NEAR_BEST_DB} dB of the best ({s['best']}, {s['best_psnr']:.2f} dB): {s['fastest_near_best']} "
              f"{s['fastest_cpu_seconds_per_frame']:.3f} CPU s/frame; CPU-time speed-up x{s['speedup_over_ddim20_cpu'] or float('nan'):.1f} "
              f"over DDIM-20, x{s['speedup_over_cycles64_cpu'] or float('nan'):.1f} over Cycles-64 "
              f"(wall x{s['speedup_over_ddim20_wall'] or float('nan'):.1f}, x{s['speedup_over_cycles64_wall'] or float('nan'):.1f})")
    for name, sec in (result.get("sections") or {}).items():
        for c in sec.get("schemes") or []:
            print(f"{name}, {c['size'][0]}x{c['size'][1]} {c['setting']}: recursive PSNR {c['psnr_recursive']:.2f} TC {c['tc_recursive']} "
                  f"{c['cpu_seconds_per_frame_recursive']:.3f} CPU s/frame; sequential PSNR {c['psnr_sequential']:.2f} TC {c['tc_sequential']} "
                  f"{c['cpu_seconds_per_frame_sequential']:.3f} CPU s/frame")
    print("wrote " + ", ".join(str(p) for p in wrote))
    return 0
