"""Markdown for `x2video eval` results: one table per experiment, model beside the classical baseline and the paper's figures."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from x2video.eval.machine import machine_label

_LETTERS = {"a": "(a)", "b": "(b)", "c": "(c)", "d": "(d)"}


def labels_below(points: list[tuple[str, float, float]], *, log_x: bool = True) -> set[int]:
    """Chart label placement for (label, seconds per frame, PSNR) points: the indices whose label goes
    below its point. A label sits above-right of its point and would cover the label of a point a
    label's width to its left (0.3 decades on a log axis, 12 % of the range on a linear one) at
    about the same PSNR (6 % of the PSNR range)."""
    if not points:
        return set()
    ys = [y for _, _, y in points]
    near = 0.06 * max(max(ys) - min(ys), 1e-9)

    def pos(x: float) -> float:
        return math.log10(x) if log_x and x > 0 else x
    xs = [pos(x) for _, x, _ in points]
    wide = 0.3 if log_x else 0.12 * max(max(xs) - min(xs), 1e-9)
    above: list[tuple[float, float]] = []
    below: set[int] = set()
    for i in sorted(range(len(points)), key=lambda i: points[i][1]):
        x, y = pos(points[i][1]), points[i][2]
        if any(0 <= x - ax < wide and abs(y - ay) < near for ax, ay in above):
            below.add(i)
        else:
            above.append((x, y))
    return below


def fmt(v: Any, digits: int = 2) -> str:
    """A number for a table cell: fixed digits, '–' when missing or not finite."""
    if v is None or isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return "–"
    return f"{v:.{digits}f}"


def cell(text: str) -> str:
    """Text safe inside a Markdown table cell ("Mask A|M|R" keeps its bars)."""
    return str(text).replace("|", "\\|")


def _spf(v: Any) -> str:
    if not isinstance(v, (int, float)) or not math.isfinite(v):
        return "–"
    return f"{v:.3f}" if v >= 0.01 else f"{v:.2g}"


def _paper(p: dict | None) -> str:
    if not p:
        return ""
    parts = [f"PSNR {p['psnr']:.2f}"] if "psnr" in p else []
    if "tc" in p:
        parts.append(f"TC {p['tc']:.4f}")
    if "seconds_per_frame" in p:
        parts.append(f"{p['seconds_per_frame']:.2f} s")
    return ", ".join(parts)


HEADER = (
    "| | FID↓ | FVD↓ | PSNR↑ | SSIM↑ | LPIPS↓ | TC↓ | s/frame↓ | classical PSNR↑ | classical SSIM↑ | classical FID↓ | classical TC↓ | paper (context) |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|"
)


def row_line(row: dict[str, Any]) -> str:
    """One Markdown table line for a results row."""
    label = cell(row["label"])
    if not row.get("available", False):
        return f"| {label} | n/a: {cell(row.get('reason', 'not run'))} |" + " – |" * 10 + f" {_paper(row.get('paper'))} |"
    m, b = row["model"], row["baseline"]
    same = f" (= {cell(row['same_render_as'])})" if row.get("same_render_as") else ""
    cells = [
        f"{label}{same}", fmt(m.get("fid")), "n/a¹", fmt(m.get("psnr")), fmt(m.get("ssim"), 4), "n/a¹", fmt(m.get("tc"), 4),
        _spf(m.get("seconds_per_frame")), fmt(b.get("psnr")), fmt(b.get("ssim"), 4), fmt(b.get("fid")), fmt(b.get("tc"), 4),
        _paper(row.get("paper")),
    ]
    return "| " + " | ".join(cells) + " |"


def table_markdown(key: str, table: dict[str, Any]) -> str:
    lines = [f"### {_LETTERS.get(key, key)} {table['title']}", "", HEADER]
    lines += [row_line(r) for r in table["rows"]]
    if table.get("notes"):
        lines.append("")
    lines += [f"- {n}" for n in table.get("notes", [])]
    if key == "c":
        quarters = quarters_markdown(table)
        if quarters:
            lines += ["", quarters]
    return "\n".join(lines)


def psnr_by_part(row: dict[str, Any], parts: int = 4) -> list[float] | None:
    """Mean PSNR (dB) of each of `parts` consecutive stretches of the shots' frames (numpy.array_split of the
    frame indices; mean over frames, then over shots), from the per-frame PSNRs in the row's per-shot results.
    None when a shot lacks them or has fewer frames than parts."""
    shots = (row.get("model") or {}).get("shots") or {}
    per_shot = []
    for s in shots.values():
        frames = s.get("psnr_frames")
        if not frames or len(frames) < parts:
            return None
        per_shot.append([float(np.mean(c)) for c in np.array_split(np.asarray(frames, np.float64), parts)])
    if not per_shot:
        return None
    return [float(v) for v in np.mean(per_shot, axis=0)]


def quarters_markdown(table: dict[str, Any]) -> str:
    """Table (c) along the shot: each row's PSNR by quarter of the long shots, and recursive minus sequential
    per quarter for each condition. Sequential sampling that accumulates error falls behind more and more
    towards the end of the shot (the paper's case); the content itself changes along a shot, so compare the
    schemes quarter by quarter rather than a quarter with the first."""
    rows = [(r, psnr_by_part(r)) for r in table["rows"] if r.get("available")]
    rows = [(r, q) for r, q in rows if q is not None]
    if not rows:
        return ""
    lines = ["PSNR by quarter of the shot (dB, mean over shots):", "",
             "| | 1st quarter | 2nd | 3rd | 4th |", "|---|---|---|---|---|"]
    lines += [f"| {cell(r['label'])} | " + " | ".join(fmt(v) for v in q) + " |" for r, q in rows]
    parts = {id(r): q for r, q in rows}
    for rec, seq in scheme_pairs([r for r, _ in rows]):
        if seq is None:
            continue
        label = "Recursive − sequential" + rec["label"][len("Recursive"):]
        lines.append(f"| {cell(label)} | " + " | ".join(f"{a - b:+.2f}" for a, b in zip(parts[id(rec)], parts[id(seq)])) + " |")
    return "\n".join(lines)


def scheme_pairs(rows: list[dict[str, Any]]) -> list[tuple[dict[str, Any], dict[str, Any] | None]]:
    """Table (c): each recursive row with the sequential row of the same condition (None when there is none)."""
    return [(rec, next((r for r in rows if r["settings"].get("scheme") == "sequential" and r["condition"] == rec["condition"]), None))
            for rec in rows if rec["settings"].get("scheme") == "recursive"]


def results_markdown(results: dict[str, Any], *, heading: str | None = "X2Video evaluation") -> str:
    """The whole results.md: tables, then what every column means and where the numbers came from."""
    out = [f"## {heading}", ""] if heading else []
    models = results.get("models", {})
    if models:
        out += [f"- Model ({role}): {_model_text(d)}" for role, d in models.items()]
        out.append("")
    data = results.get("data", {})
    for key, d in data.items():
        out.append(f"- Data ({key}): {d.get('description', '')}")
    if results.get("settings", {}).get("replace_refs"):
        out.append("- Sampling: reference frames held at their noised latents between steps (`--replace-refs`)")
    else:  # results from before the option existed hold no setting: they re-estimated the references
        out.append("- Sampling: each window re-estimates its reference frames (`--no-replace-refs`)")
    noise = results.get("settings", {}).get("noise", "window")  # results from before the option: per window
    if noise == "frame":  # noise_shared is ignored with per-window noise
        shared = results["settings"].get("noise_shared", 0.0)
        out.append(f"- Initial noise: per frame of the shot (`--noise frame`), {shared:g} of its variance shared by all frames (`--noise-shared {shared:g}`)")
    else:
        out.append("- Initial noise: per window (`--noise window`)")
    if results.get("settings", {}).get("seams"):
        out.append("- Recursive rows: keyframes re-generated with their neighbours after the first interpolation level (`--seams`)")
    dc = results.get("settings", {}).get("ref_dc", 0.0)  # results from before the option: off
    if dc:
        out.append(f"- Interpolation windows: generated frames' latent mean pulled {dc:g} of the way to the interpolation of their "
                   f"references' (`--ref-dc {dc:g}`)")
    if results.get("settings", {}).get("resample", 1) != 1:
        r = results["settings"]["resample"]
        out.append(f"- DDIM rows: windows with reference frames take each step but the first and last {r} times (RePaint's resampling, `--resample {r}`)")
    if results.get("settings", {}).get("max_levels") is not None:
        k = results["settings"]["max_levels"]
        out.append(f"- Recursive rows: at most {k} level{'s' if k != 1 else ''} (`--max-levels {k}`): the keyframes are (N-1)^(K-1) "
                   "frames apart in chained keyframe windows")
    if data:
        out.append("")
    for key, table in results["tables"].items():
        out.append(table_markdown(key, table))
        out.append("")
    out.append("Columns: FID/PSNR/SSIM/TC/s per frame of the model against the ground truth; *classical* = "
               f"{results.get('baseline', 'classical shading')}, scored the same way.")
    out.append(f"Ground truth: {results.get('ground_truth', '')}" + (f"; truth: {results['truth']}." if results.get("truth") else "."))
    unav = results.get("unavailable", {})
    if unav:
        out.append("¹ " + " ".join(f"{k.upper()} not computed: {v['reason']}." for k, v in unav.items()))
    defs = results.get("definitions", {})
    for k in ("psnr", "ssim", "fid", "tc", "seconds_per_frame"):
        if k in defs:
            out.append(f"- {k}: {defs[k]}")
    if results.get("paper_note"):
        out.append(f"- paper column: {results['paper_note']}")
    mach = results.get("machine")
    if mach:
        out.append(f"\nMachine: {machine_label(mach)}; torch {mach.get('torch')}; commit {mach.get('git_commit')}. "
                   f"Wall time {results.get('wall_seconds', 0):.0f} s (metrics {results.get('metric_seconds', 0):.0f} s).")
    if results.get("command"):
        out.append(f"\nReproduce: `{results['command']}`")
    return "\n".join(out) + "\n"


def _model_text(d: dict) -> str:
    if "missing" in d:
        return f"(missing: {d['missing']})"
    bits = [str(d.get("path", "?"))]
    if d.get("untrained"):
        bits.append("UNTRAINED random weights")
    if d.get("config"):
        bits.append(f"preset {d['config']}")
    if d.get("step") is not None:
        bits.append(f"step {d['step']}")
    if d.get("encoder_dtype"):
        bits.append(f"VAE encoder in {d['encoder_dtype']} (`--bf16-encoder`)")
    if d.get("channel_encoder") == "distilled":
        bits.append("channels encoded by the distilled encoder (`--channel-encoder`)")
    return "(" + ", ".join(bits) + ")"
