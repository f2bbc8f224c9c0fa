"""The indexes of the results: bench/results/README.md (one table per bench, every file, in date order) and
docs/evaluations/README.md (the evaluation log, in date order), each row titled with what it measured.

    python -m bench.index            # rewrite both (and record the date of a result seen for the first time)
    python -m bench.index --check    # write nothing: exit 1 when an index differs from what the files give

A result's title is its JSON's `description` field where it has one, else what its bench measures (WHAT) and the
settings its recorded command (or `info`) gives; its date is the JSON's `date` field, else the date recorded in
bench/results/index.json (the day git first saw the file, or the day this command first saw it). A log entry's
title is its first heading, with, for an `x2video eval` entry, the tables it holds and the data they ran on.
"""
from __future__ import annotations

import argparse
import datetime
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

from bench.common import RESULTS

ROOT = RESULTS.parents[1]
LOG = ROOT / "docs" / "evaluations"
#: {path under bench/results: YYYY-MM-DD} for the results whose JSON records no date
DATES = RESULTS / "index.json"

#: what each bench measures, as its row's title begins
WHAT = {
    "attention": "Attention layer time and memory: Hybrid Self-Attention vs self vs full spatio-temporal",
    "bigframes": "Large frames: seconds per frame and peak memory per tier, PSNR beside the formula",
    "editor_latency": "Editor latency: how soon the editor shows the window, the formula's frame, tier 1's, a diffusion keyframe",
    "edits": ("Edits over the shot's own path-traced frames against Cycles' re-render of each edit, inside the edit and whole "
              "frame, beside doing nothing and the rebuild from passes"),
    "farm": "x2video farm throughput on a local Ray cluster",
    "lcm_speedup": "LCM-2 vs DDIM-20 back to back, repeated",
    "light_budget": "Where the formula's error lies on path-traced shots: the PSNR each missing light term would add",
    "noise_prior": "PSNR and TC of per-window vs shared per-frame noise over several seeds",
    "pareto": "Speed vs accuracy chart: every tier, step count and Cycles",
    "pathtraced": "Each tier beside the formula on path-traced shots, per material class",
    "recursive_seams": "TC of recursive vs sequential sampling: same-window pairs vs seams, by level and side",
    "render": "Render speed: seconds per frame and peak memory",
    "side_by_side": "The README's picture: one outside frame by each tier and Cycles, with PSNR and seconds",
    "speed_accuracy": "Speed vs PSNR/SSIM/TC of the sampler presets",
    "stability": "Stability grid: where each method fails (crash, non-finite, far below the formula)",
    "vs_cycles": "The fast and quality presets vs Cycles 32 spp + denoising on the same room",
}
#: command flags that name where a result went, not what it measured
QUIET_FLAGS = {"--out", "--name", "--no-docs", "--json", "--no-png"}


def _read_json(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ValueError(f"{path.relative_to(ROOT)}: unreadable result JSON ({e})") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path.relative_to(ROOT)}: a result JSON holds an object, not {type(doc).__name__}")
    return doc


def _short(value: str) -> str:
    """A data set or run folder by its last part: DATA/pt160 -> pt160, ~/.cache/.../cycles-v3-... -> cycles-v3-..."""
    return ",".join(v.rstrip("/").rsplit("/", 1)[-1] if "/" in v else v for v in value.split(","))


def settings(command: str) -> str:
    """'--tiers formula,residual --data DATA/pt160' -> 'tiers formula,residual, data pt160' (where-to-write flags left out)."""
    try:
        words = shlex.split(command)
    except ValueError:
        words = command.split()
    words = words[3:] if words[:2] == ["python", "-m"] else words[2:] if words[:1] == ["python"] else words
    out: list[str] = []
    i = 0
    while i < len(words):
        w = words[i]
        value = words[i + 1] if i + 1 < len(words) and not words[i + 1].startswith("--") else None
        i += 2 if value is not None else 1
        if not w.startswith("--") or w in QUIET_FLAGS:
            continue
        name = w[2:].replace("-", " ")
        out.append(name if value is None else f"{name} {_short(value) if '/' in value else value or repr(value)}")
    return ", ".join(out)


def _commit(doc: dict) -> str:
    """The commit a result ran at: its machine's, else its first run's."""
    machine = doc.get("machine")
    if not isinstance(machine, dict) and isinstance(doc.get("runs"), dict):
        machine = next((v for v in doc["runs"].values() if isinstance(v, dict)), None)
    return str(machine.get("git_commit") or "")[:7] if isinstance(machine, dict) else ""


def title(folder: str, doc: dict) -> str:
    if doc.get("description"):
        return str(doc["description"])
    what = WHAT.get(folder, folder.replace("_", " "))
    if doc.get("command"):
        how = settings(str(doc["command"]))
    else:
        info = doc.get("info") or {}
        how = ", ".join(f"{k} {v}" for k, v in info.items() if not isinstance(v, (dict, list)))
    return f"{what}; {how}" if how else what


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def first_heading(path: Path) -> str:
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            return line.lstrip("#").strip()
    raise ValueError(f"{path.relative_to(ROOT)}: no heading to title it by")


# --------------------------------------------------------------------------------------------- bench/results
def result_files() -> list[Path]:
    """Every file under bench/results but the index itself and its dates."""
    return sorted(p for p in RESULTS.rglob("*") if p.is_file() and p not in (RESULTS / "README.md", DATES))


def rows_of(folder: Path, dates: dict[str, str]) -> list[tuple[str, str, str]]:
    """(date, name, row) per result of `folder`: a JSON with its Markdown and PNG of the same name beside it; a
    Markdown or PNG with no JSON of its name is a row of its own."""
    files = sorted(p for p in folder.iterdir() if p.is_file())
    stems = {p.stem for p in files if p.suffix == ".json"}
    out = []
    for p in files:
        if p.suffix != ".json" and p.stem in stems:
            continue  # shown in its JSON's row
        rel = f"{folder.name}/{p.name}"
        if p.suffix == ".json":
            doc = _read_json(p)
            date = str(doc.get("date") or dates.get(rel) or "")[:10]
            extras = [f"[{q.suffix[1:]}]({folder.name}/{q.name})" for q in files if q.stem == p.stem and q.suffix != ".json"]
            what, command, commit = title(folder.name, doc), doc.get("command") or "", _commit(doc)
        else:
            date, extras, command, commit = dates.get(rel, ""), [], "", ""
            what = first_heading(p) if p.suffix == ".md" else f"{WHAT.get(folder.name, folder.name)} (image)"
        if not date:
            raise ValueError(f"bench/results/{rel}: no date (no 'date' field, not in {DATES.name}): run python -m bench.index")
        name = f"[{p.name}]({rel})" + (f" ({', '.join(extras)})" if extras else "")
        out.append((date, p.name, f"| {date} | {name} | {_cell(what)} | {'`' + _cell(command) + '`' if command else ''} | {commit} |"))
    return sorted(out)


def results_index(dates: dict[str, str]) -> str:
    lines = ["# Benchmark results", "",
             "One folder per bench (`python -m bench.NAME`, NAME the folder), written by the bench's `--out` (default",
             "bench/results/NAME/NAME.json). Paths inside are repository-relative or placeholders (DATA/ a data set",
             "from `x2video dataset make`, RUNS/ a training run); the command reproduces the file. Each table is in date",
             "order (the JSON's `date`, else the day the file was first committed, kept in `index.json`); a title is the",
             "JSON's `description`, else what the bench measures and the settings of its command. Written by",
             "`python -m bench.index`, not by hand (tests/test_result_indexes.py checks it). The editor's",
             "speed-vs-accuracy chart plots every row of these files that has seconds per frame and PSNR.", ""]
    for folder in sorted(p for p in RESULTS.iterdir() if p.is_dir()):
        lines += [f"## {folder.name}", "", "| date | result | what it measured | command | commit |", "|---|---|---|---|---|"]
        lines += [row for _, _, row in rows_of(folder, dates)] + [""]
    return "\n".join(lines)


def _git_added(path: Path) -> str | None:
    try:
        out = subprocess.run(["git", "log", "--diff-filter=A", "--follow", "--format=%as", "--", str(path)], cwd=ROOT,
                             capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return None
    days = out.stdout.split()
    return days[-1] if out.returncode == 0 and days else None


def load_dates() -> dict[str, str]:
    return json.loads(DATES.read_text(encoding="utf-8")) if DATES.is_file() else {}


def dates_with_new(dates: dict[str, str]) -> dict[str, str]:
    """`dates` plus a date for each result that records none and is not in it yet (git's first commit of it, else today)."""
    out = dict(dates)
    for p in result_files():
        rel = p.relative_to(RESULTS).as_posix()
        if rel in out or (p.suffix == ".json" and _read_json(p).get("date")):
            continue
        if p.suffix != ".json" and p.with_suffix(".json").is_file():
            continue  # in its JSON's row
        out[rel] = _git_added(p) or datetime.date.today().isoformat()
    return dict(sorted(out.items()))


# --------------------------------------------------------------------------------------------- docs/evaluations
TABLE = re.compile(r"^## \((?P<t>[a-d])\) (?P<title>.+)$")


def _data(lines: list[str], kind: str) -> str:
    """'4 test room(s) of DATA/r160, 17 frames at 160x112' from an eval entry's '- Data (kind): ...' line."""
    prefix = f"- Data ({kind}): "
    line = next((ln[len(prefix):] for ln in lines if ln.startswith(prefix)), "")
    return re.sub(r" \([^)]*\)", "", line).split(": ", 1)[0]


def log_title(path: Path) -> tuple[str, str, str]:
    """(title, tables, video weights) of a log entry."""
    lines = path.read_text(encoding="utf-8").splitlines()
    head = first_heading(path)
    tables = [m for ln in lines if (m := TABLE.match(ln))]
    weights = next((ln.split(": (", 1)[1].split(",")[0] for ln in lines if ln.startswith("- Model (video): (")), "")
    if not weights and re.match(r"^\d{4}-\d\d-\d\d-(evaluation|speedup)-\d+$", path.stem):  # made by x2video.eval.card
        weights = next((m.group(1) for ln in lines[:6] if (m := re.search(r"--weights (\S+)", ln))), "(shipped)")
    if tables:
        data = {k: _data(lines, k) for k in ("main", "long")}
        what = "; ".join(f"({m.group('t')}) {m.group('title')}" for m in tables)
        used = [data["long"] if m.group("t") == "c" else data["main"] for m in tables]
        on = "; ".join(dict.fromkeys(u for u in used if u))
        head = f"{head}: {what}" + (f", on {on}" if on else "")
    return head, "".join(m.group("t") for m in tables), weights.strip("`")


def log_index() -> str:
    entries = sorted((p for p in LOG.glob("*.md") if p.name != "README.md"), key=lambda p: (p.name[:10], p.stem))
    rows = []
    for p in entries:
        head, tables, weights = log_title(p)
        rows.append(f"| {p.name[:10]} | [{p.stem}]({p.name}) | {_cell(head)} | {tables} | {_cell(weights)} |")
    return "\n".join([
        "# Evaluation log",
        "",
        "Append-only: one dated file per evaluation (`x2video eval`, added by `python -m x2video.eval.card RESULTS...",
        "[--speedup JSON...] --log docs/evaluations`), per back-to-back speed-up (`python -m bench.lcm_speedup`) and per",
        "session's measurements. An entry is never edited after it is written; a later measurement is a new entry.",
        "Machine paths are placeholders: DATA/ (data sets from `x2video dataset make`), RUNS/ (training runs), RESULTS/",
        "(`x2video eval --out` folders), TMP/. The model card (resources/MODEL_CARD.md) gives what the shipped weights",
        "score now, written from the result JSON by `python -m bench.card`; the notebook holds the reasoning behind",
        "older entries.",
        "",
        "This index is written by `python -m bench.index` (in date order; a title is the entry's first heading, with the",
        "tables of an `x2video eval` entry and the data they ran on). `x2video.eval.card --log` rewrites it in a shorter",
        "form: run `python -m bench.index` after it (tests/test_result_indexes.py fails until then).",
        "",
        "| date | entry | what it measured | tables | video weights (x2video eval entries) |",
        "|---|---|---|---|---|",
        *rows,
    ]) + "\n"


def expected(dates: dict[str, str]) -> dict[Path, str]:
    return {RESULTS / "README.md": results_index(dates), LOG / "README.md": log_index()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.index", description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 if an index differs from what the files give")
    args = ap.parse_args(argv)
    try:
        dates = load_dates() if args.check else dates_with_new(load_dates())
        want = expected(dates)
    except ValueError as e:
        print(f"bench.index: error: {e}", file=sys.stderr)
        return 2
    stale = [p for p, text in want.items() if not p.is_file() or p.read_text(encoding="utf-8") != text]
    if args.check:
        for p in stale:
            print(f"{p.relative_to(ROOT)}: stale (python -m bench.index rewrites it)")
        return 1 if stale else 0
    from x2video.io.atomic import write_text_atomic

    if dates != load_dates():
        write_text_atomic(DATES, json.dumps(dates, indent=1) + "\n")
        print(f"wrote {DATES.relative_to(ROOT)}")
    for p in stale:
        write_text_atomic(p, want[p])
        print(f"wrote {p.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
