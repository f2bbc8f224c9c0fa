"""bench.pareto's chart (docs/pareto.png): PSNR and TC against seconds per frame (log), one line per family and size,
a row of two panels per section; matplotlib."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from bench.pareto.inputs import input_costs, with_inputs
from bench.pareto.methods import FAMILY_NAMES
from bench.pareto.report import shots_text
from x2video.tiers import registry as tiers

FAMILY_STYLE = {"formula": ("s", "black"), "residual": ("D", "tab:green"), "ddim-recursive": ("o", "tab:blue"),
                "ddim-sequential": ("o", "tab:cyan"), "lcm-recursive": ("^", "tab:orange"), "lcm-sequential": ("^", "gold"),
                "cycles": ("*", "tab:red")}


def _gt_line(ground_truth: dict) -> str:
    gts = {(v["kind"], str(v["samples"])) for v in ground_truth.values()}
    if len(gts) == 1 and len(ground_truth) > 1:
        v = next(iter(ground_truth.values()))
        return f"{'Cycles' if v['kind'] == 'bench reference' else 'the data set'} at {v['samples']} spp + OIDN, every size"
    return "; ".join(f"{k}: {'Cycles' if v['kind'] == 'bench reference' else 'the data set'} at {v['samples']} spp + OIDN"
                     + (" (own noise seed)" if v["kind"] == "bench reference" else "") for k, v in ground_truth.items())


def _main_run(rows: list[dict]) -> Any:
    """The run that measured most of these rows (the others are tagged on the chart)."""
    runs = [r.get("run") for r in rows]
    return max(set(runs), key=runs.count) if runs else None


def _panels(axes: Any, rows: list[dict], clock: str | None) -> list[tuple[int, int]]:
    """PSNR and TC against seconds per frame (log) on two axes: one line per family and size (solid the smallest size,
    dashed the next), the formula a horizontal line per size; a row from another run than most is tagged [run k]."""
    sizes = sorted({tuple(r["size"]) for r in rows}, key=lambda s: s[0] * s[1])
    dashes = {s: ("-" if i == 0 else "--" if i == 1 else ":") for i, s in enumerate(sizes)}
    usual = _main_run(rows)
    for ax, key, ylabel in ((axes[0], "psnr", "PSNR (dB) ↑"), (axes[1], "tc", "TC (warping error / ground truth's) ↓")):
        for size in sizes:
            rs = [r for r in rows if tuple(r["size"]) == size and r.get(key) is not None]
            form = next((r for r in rs if r["kind"] == tiers.FORMULA), None)
            if form is not None:
                ax.axhline(form[key], color="black", lw=0.8, ls=dashes[size], alpha=0.5)
            for fam in dict.fromkeys(r["family"] for r in rs):
                pts = sorted((r for r in rs if r["family"] == fam), key=lambda r: r["seconds_per_frame"])
                marker, colour = FAMILY_STYLE.get(fam, ("x", "grey"))
                ax.plot([r["seconds_per_frame"] for r in pts], [r[key] for r in pts], ls=dashes[size], marker=marker, color=colour,
                        ms=7 if marker != "*" else 11, label=f"{FAMILY_NAMES.get(fam, fam)} {size[0]}x{size[1]}")
                for r in pts:  # the passes' own Cycles render, when rendered for this: a dotted segment to an open marker
                    total = r.get("seconds_rendered_for_this")
                    if r.get("inputs") and total:
                        ax.plot([r["seconds_per_frame"], total], [r[key], r[key]], ls=":", lw=0.9, color=colour, alpha=0.7)
                        ax.plot([total], [r[key]], marker=marker, mfc="none", color=colour, ms=6, ls="none")
                for r in pts:
                    tag = r["label"].replace(" + OIDN", "").replace("tier 1 (residual net)", "tier 1").replace("formula (tier 0)", "formula")
                    tag = tag.replace(" sequential", " seq") + (f" [run {r['run']}]" if r.get("run") not in (None, usual) else "")
                    ax.annotate(tag, (r["seconds_per_frame"], r[key]), textcoords="offset points", xytext=(4, 3), fontsize=6, color=colour)
        ax.set_xscale("log")
        ax.set_xlabel(("CPU seconds per frame, all threads" if clock == "cpu" else "wall seconds per frame") + " (log) ↓")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, which="both")
    return sizes


def _runs_line(result: dict) -> str:
    runs = result.get("runs") or []
    if not runs:
        return f"load {result['load_average_start'][0]:.1f}"
    return "; ".join(f"run {r['id']} {str(r.get('date') or '?')[:10]} load {((r.get('load_average_start') or [float('nan')])[0]):.1f}: "
                     + (", ".join(r["methods"]) if len(r["methods"]) <= 4 else f"{len(r['methods'])} methods")
                     + (f" ({r['section']})" if r.get("section") else "") for r in runs)


def draw(result: dict, path: Path) -> Path:
    """Two panels, PSNR and TC against seconds per frame (log), for the main rows (`_panels`); a row of two more per
    section (`--section`: e.g. recursive against sequential sampling on a longer shot)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from x2video.eval.machine import machine_label
    from x2video.io.atomic import atomic_path

    costs = input_costs()
    ok = lambda rs: [with_inputs(r, costs) for r in rs if r.get("psnr") is not None and r["seconds_per_frame"] > 0]  # noqa: E731
    rows = ok(result["rows"])
    if not rows:
        raise ValueError("pareto chart: no row with PSNR and seconds per frame")
    sections = [(name, sec, ok(sec["rows"])) for name, sec in (result.get("sections") or {}).items() if ok(sec["rows"])]
    fig, axes = plt.subplots(1 + len(sections), 2, figsize=(12, 5 + 4.2 * len(sections)), dpi=110, squeeze=False)
    sizes = _panels(axes[0], rows, result.get("clock"))
    handles, labels = axes[0][0].get_legend_handles_labels()
    for i, (name, sec, srows) in enumerate(sections, start=1):
        _panels(axes[i], srows, result.get("clock"))
        shots = "; ".join(f"{k}: {shots_text(g)}, ground truth "
                          f"{'Cycles' if g['kind'] == 'bench reference' else 'the data set'} at {g['samples']} spp + OIDN"
                          for k, g in sec["ground_truth"].items())
        axes[i][0].set_title(f"{name}: {shots}", fontsize=8, loc="left")
        for h, lab in zip(*axes[i][0].get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), fontsize=7, frameon=False)
    fig.suptitle(f"speed vs accuracy on path-traced test rooms ({machine_label(result['machine'])}, {result['threads']} threads; "
                 f"{_runs_line(result)})\nground truth: {_gt_line(result['ground_truth'])}\nformula: horizontal line; solid = "
                 f"{sizes[0][0]}x{sizes[0][1]}" + (f", dashed = {sizes[1][0]}x{sizes[1][1]}" if len(sizes) > 1 else "")
                 + "; filled marker: the passes already rendered (editing an existing shot); dotted to an open marker: the passes"
                 " rendered for this (their Cycles render's CPU seconds added)", fontsize=8)
    top = 1 - 0.55 / fig.get_figheight()
    fig.tight_layout(rect=(0, (0.5 if len(labels) > 6 else 0.3) / fig.get_figheight(), 1, top))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path
