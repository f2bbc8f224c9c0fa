"""The model card and the evaluation log (issue 5, "Done means"; issue 32).

    python -m x2video.eval.card --card docs/model_card.md --out resources/MODEL_CARD.md
    python -m x2video.eval.card RESULTS_DIR [RESULTS_DIR ...] [--speedup LCM_SPEEDUP_JSON ...] --log docs/evaluations
    python -m x2video.eval.card RESULTS_DIR [...] [--run RUN_DIR ...] [--speedup JSON ...] [--renders DIR] [--out FILE]

The first builds the card whole: the hand-written source with each `<!-- headline ENTRY (x) -->`
line replaced by that table of the log entry ENTRY, cut to the headline columns, the formula's
beside every row. The second adds one dated file per evaluation and per speed-up to the
append-only log (`docs/evaluations/`), machine paths replaced by placeholders. The third writes
every table of the given results (and training runs) as one report. Every number is read from a
results.json (with the exact command that produced it), a training run's state.json / summary.json /
log.json / results.json, or a log entry made from them; nothing is typed in by hand.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import re
import shlex
import sys
from pathlib import Path
from typing import Any

from x2video.eval.checks import orderings, orderings_markdown, speedup_checks
from x2video.eval.report import results_markdown
from x2video.io.paths import scrub_paths


def _read(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: cannot read JSON ({e})") from None


def load_results(path: str | Path) -> dict[str, Any]:
    """results.json of an `x2video eval` folder (or the file itself); checks its format."""
    p = Path(path)
    f = p / "results.json" if p.is_dir() else p
    if not f.is_file():
        raise FileNotFoundError(f"{p}: no results.json (run `x2video eval ... --out {p}` first)")
    doc = _read(f)
    if not isinstance(doc, dict) or doc.get("format") != "x2video-eval":
        raise ValueError(f"{f}: not an `x2video eval` results file (format {doc.get('format') if isinstance(doc, dict) else None!r})")
    return doc


def load_speedup(path: str | Path) -> dict[str, Any]:
    """A `bench/lcm_speedup.py` result file; checks its format."""
    f = Path(path)
    if not f.is_file():
        raise FileNotFoundError(f"{f}: no such file (run `python bench/lcm_speedup.py ... --out {f}` first)")
    doc = _read(f)
    if not isinstance(doc, dict) or doc.get("format") != "x2video-lcm-speedup" or not doc.get("repeats"):
        raise ValueError(f"{f}: not a `bench/lcm_speedup.py` result (format {doc.get('format') if isinstance(doc, dict) else None!r})")
    return doc


def speedup_markdown(bench: dict[str, Any], heading: str) -> str:
    """One back-to-back speed measurement: how it ran, seconds per frame per repeat, the (d) ordering."""
    m = bench.get("machine", {})
    rooms = bench.get("data", {}).get("rooms", [])
    lines = [f"## {heading}", "",
             f"`{bench.get('command')}` — {m.get('cpu')} ({m.get('cpu_cores')} cores, {m.get('torch_threads')} torch "
             f"threads, torch {m.get('torch')}, device {m.get('device')}, commit {m.get('git_commit')}); "
             f"{len(rooms)} held-out shots of {bench.get('data', {}).get('frames')} frames, "
             f"{bench.get('wall_seconds', 0):.0f} s. DDIM-20 and LCM-2 rendered back to back, which goes first alternating.", ""]
    names = [r["name"] for r in bench["repeats"][0]["rows"]]
    lines += ["| repeat | order | " + " | ".join(f"{n} s/frame (encoding)" for n in names) + " | speed-up | + Ref. | no encoding |",
              "|---|---|" + "---|" * (len(names) + 3)]
    for i, rep in enumerate(bench["repeats"]):
        by = {r["name"]: r for r in rep["rows"]}
        cells = [f"{by[n]['seconds_per_frame']:.3f} ({by[n]['encode_seconds_per_frame']:.3f})" for n in names]
        lines.append(f"| {i + 1} | {' then '.join(rep['order'])} | " + " | ".join(cells)
                     + f" | {rep['speedup']:.2f}x | {rep['speedup_ref']:.2f}x | {rep['speedup_no_encoding']:.2f}x |")
    lines += ["", orderings_markdown(speedup_checks(bench)), ""]
    return "\n".join(lines)


def run_facts(run: str | Path) -> dict[str, Any]:
    """Training facts of one run folder: stage, steps, speed, machine, estimated hours, stage results."""
    from x2video.train.loop import latest_checkpoint

    run = Path(run)
    if not run.is_dir():
        raise FileNotFoundError(f"training run {run} does not exist")
    ck = latest_checkpoint(run)
    if ck is None:
        raise FileNotFoundError(f"{run}: no step-*/state.json checkpoint; is it a training run folder?")
    state = _read(ck / "state.json")
    sc = state.get("stage_config", {})
    facts: dict[str, Any] = {"run": str(run), "stage": sc.get("stage", "?"), "step": state.get("step"), "checkpoint": ck.name,
                             "batch": sc.get("batch"), "loop": state.get("loop", {}), "stage_config": sc}
    if (run / "summary.json").is_file():
        facts["last_session"] = _read(run / "summary.json")
    if (run / "log.json").is_file():
        log = _read(run / "log.json")
        rates = [e["steps_per_s"] for e in log if isinstance(e, dict) and e.get("steps_per_s")]
        if rates:
            facts["estimated_hours"] = sum(1.0 / r for r in rates) / 3600.0
            facts["final_loss"] = log[-1].get("loss")
            facts["logged_steps"] = len(log)
    if (run / "results.json").is_file():
        facts["results"] = _read(run / "results.json")
    return facts


def _fmt(v: Any, digits: int = 3) -> str:
    return f"{v:.{digits}g}" if isinstance(v, (int, float)) and not isinstance(v, bool) else "–"


def training_markdown(runs: list[dict[str, Any]]) -> str:
    lines = [
        "| stage | run | steps | est. hours¹ | last session: steps/s | samples/s | seconds | device | final loss | stage results |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for f in runs:
        s = f.get("last_session", {})
        res = f.get("results", {}).get(f["stage"], {}) if isinstance(f.get("results"), dict) else {}
        extra = ""
        if isinstance(res, dict) and res.get("heldout_psnr_db"):
            extra = "held-out VAE PSNR " + ", ".join(f"{k} {v:.2f} dB" for k, v in res["heldout_psnr_db"].items())
        elif isinstance(res, dict) and res.get("heldout_v_loss"):
            prior = ("on, residual target" if res.get("residual_prior") else "on") if res.get("shading_prior") else "off"
            extra = ("shading prior " + prior + "; held-out v-loss "
                     + ", ".join(f"{k} {v:.4f}" for k, v in res["heldout_v_loss"].items()))
        lines.append(
            f"| {f['stage']} | `{f['run']}` | {f['step']} | {_fmt(f.get('estimated_hours'))} | {_fmt(s.get('steps_per_s'))} | "
            f"{_fmt(s.get('samples_per_s'))} | {_fmt(s.get('seconds'), 5)} | {s.get('device', '–')} | {_fmt(f.get('final_loss'))} | {extra} |"
        )
    lines.append("\n¹ estimated from the loss log: the sum of 1/(steps/s) over logged steps (covers every resumed session).")
    lines.append("\nStage settings (from each run's newest state.json; `x2video train STAGE` with these values resumes or repeats it):\n")
    for f in runs:
        settings = {k: v for k, v in f.get("stage_config", {}).items() if k != "model"}
        loop = {k: f["loop"][k] for k in ("steps", "lr", "ema_decay", "seed", "mixed_precision") if k in f.get("loop", {})}
        lines.append(f"- {f['stage']} (`{f['run']}`): `{json.dumps(settings, sort_keys=True)}`, loop `{json.dumps(loop, sort_keys=True)}`")
    return "\n".join(lines)


def card_markdown(results: list[dict[str, Any]], runs: list[dict[str, Any]], renders: Path | None = None,
                  command: str | None = None, preface: str | None = None, speedups: list[dict[str, Any]] | None = None) -> str:
    """The whole model card."""
    out = ["# X2Video model card", ""]
    out.append(f"Generated {_dt.date.today().isoformat()}" + (f" by `{command}`" if command else "") + ". Every figure below "
               "comes from the results files and training runs named with it; rerun the command shown to reproduce it.")
    out.append("")
    if any(d.get("untrained") for r in results for d in r.get("models", {}).values() if isinstance(d, dict)):
        out += ["> **These results were measured with UNTRAINED (random) weights: they test the pipeline, not the model.**", ""]
    if preface:
        out += [preface.strip(), ""]
    if runs:
        out += ["## Training", "", training_markdown(runs), ""]
    for i, r in enumerate(results):
        out.append(results_markdown(r, heading=f"Evaluation {i + 1}" if len(results) > 1 else "Evaluation"))
        out += ["### Orderings the paper reports, on these numbers", "", orderings_markdown(orderings(r)), ""]
    for b in speedups or []:
        out.append(speedup_markdown(b, _speedup_heading(b)))
    if renders is not None:
        pngs = sorted(Path(renders).glob("*.png"))
        if pngs:
            out += ["## Renders of held-out shots (ground truth | image model | video model)", ""]
            for p in pngs:
                mp4 = p.with_suffix(".mp4")
                out.append(f"![{p.stem}]({p.as_posix()})" + (f" ([MP4]({mp4.as_posix()}))" if mp4.is_file() else ""))
            out.append("")
    return "\n".join(out) + "\n"


LOG_ENTRY = re.compile(r"^(\d{4}-\d\d-\d\d)-(evaluation|speedup)-(\d+)\.md$")


def _log_numbers(log_dir: Path, kind: str) -> list[int]:
    return [int(m.group(3)) for p in log_dir.glob("*.md") if (m := LOG_ENTRY.match(p.name)) and m.group(2) == kind]


def _as_entry(markdown: str) -> str:
    """A section of `card_markdown` as a document of its own: headings one level up."""
    return "\n".join(ln[1:] if ln.startswith("##") else ln for ln in markdown.splitlines()).rstrip() + "\n"


def write_log(log_dir: Path, results: list[dict[str, Any]], speedups: list[dict[str, Any]], command: str,
              date: str | None = None) -> list[Path]:
    """Add one dated file per evaluation and per speed-up to the evaluation log `log_dir` (numbered on from
    the last of each kind; a file never changes once written), machine paths replaced by placeholders."""
    date = date or _dt.date.today().isoformat()
    log_dir.mkdir(parents=True, exist_ok=True)
    first_e = max(_log_numbers(log_dir, "evaluation"), default=0) + 1
    first_s = max(_log_numbers(log_dir, "speedup"), default=0) + 1
    entries = []
    for i, r in enumerate(results):
        n = first_e + i
        md = results_markdown(r, heading=f"Evaluation {n} ({date})")
        md += "\n### Orderings the paper reports, on these numbers\n\n" + orderings_markdown(orderings(r)) + "\n"
        entries.append((log_dir / f"{date}-evaluation-{n:02d}.md", md))
    for i, b in enumerate(speedups):
        n = first_s + i
        entries.append((log_dir / f"{date}-speedup-{n:02d}.md", speedup_markdown(b, f"Speed-up {n} ({date}): {_speedup_heading(b)}")))
    from x2video.io.atomic import write_text_atomic

    for path, md in entries:
        head, _, rest = _as_entry(md).partition("\n")
        write_text_atomic(path, scrub_paths(f"{head}\n\nAdded by `{command}`.\n{rest}"))
    write_text_atomic(log_dir / "README.md", log_index(log_dir))
    return [path for path, _ in entries]


def log_index(log_dir: Path) -> str:
    """README.md of the evaluation log: what it is and one row per entry (title, tables, video weights)."""
    rows = []
    for p in sorted(log_dir.glob("*.md")):
        if p.name == "README.md":
            continue
        lines = p.read_text(encoding="utf-8").splitlines()
        tables = "".join(ln[4] for ln in lines if re.match(r"^## \([a-d]\)", ln))
        weights = next((ln.split(": (", 1)[1].split(",")[0] for ln in lines if ln.startswith("- Model (video): (")), "")
        if not weights and LOG_ENTRY.match(p.name):
            weights = next((m.group(1) for ln in lines[:6] if (m := re.search(r"--weights (\S+)", ln))), "(shipped)")
        rows.append(f"| [{p.stem}]({p.name}) | {lines[0].lstrip('# ')} | {tables} | {weights.strip('`')} |")
    return "\n".join([
        "# Evaluation log",
        "",
        "Append-only: one dated file per evaluation (`x2video eval`) and per back-to-back speed-up",
        "(`python -m bench.lcm_speedup`), written by `python -m x2video.eval.card RESULTS... [--speedup JSON...]",
        "--log docs/evaluations`, which also rewrites this index. An entry is never edited after it is",
        "written; a later measurement is a new entry. Machine paths are placeholders: DATA/ (data sets",
        "from `x2video dataset make`), RUNS/ (training runs), RESULTS/ (`x2video eval --out` folders),",
        "TMP/. The model card (resources/MODEL_CARD.md) quotes the headline entries that",
        "docs/model_card.md names; the notebook holds the reasoning and session notes behind them.",
        "",
        "| entry | title | tables | video weights |",
        "|---|---|---|---|",
        *rows,
    ]) + "\n"


#: a line of the card's source that becomes a headline table: `<!-- headline ENTRY (x) -->`, ENTRY a log file's name
HEADLINE = re.compile(r"^<!-- headline (?P<entry>\S+\.md) \((?P<table>[a-d])\) -->$")
#: the columns a headline table keeps, as the log's tables name them, and what the card calls them
HEADLINE_COLUMNS = (("PSNR↑", "PSNR↑"), ("SSIM↑", "SSIM↑"), ("TC↓", "TC↓"), ("s/frame↓", "s/frame↓"),
                    ("classical PSNR↑", "formula PSNR↑"), ("classical TC↓", "formula TC↓"))


def _markdown_table(lines: list[str], start: int) -> list[list[str]]:
    """The rows (header first, the |---| line dropped) of the Markdown table at or after `lines[start]`."""
    i = next(i for i in range(start, len(lines)) if lines[i].startswith("|"))
    rows = []
    while i < len(lines) and lines[i].startswith("|"):
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", lines[i].strip())[1:-1]]
        if not all(set(c) <= {"-", ":"} for c in cells):
            rows.append(cells)
        i += 1
    return rows


def _escape_pipes(text: str) -> str:
    return re.sub(r"(?<!\\)\|", r"\\|", text)


def headline_table(entry: Path, table: str, link: str) -> list[str]:
    """Table (`table`) of the log entry `entry`, cut to the headline columns with the formula's beside each
    row, then where it comes from and the command that reproduces it."""
    lines = entry.read_text(encoding="utf-8").splitlines()
    at = next((i for i, ln in enumerate(lines) if ln.startswith(f"## ({table})")), None)
    if at is None:
        raise ValueError(f"{entry}: no table ({table})")
    header, *rows = _markdown_table(lines, at)
    cols = [header.index(name) for name, _ in HEADLINE_COLUMNS]
    out = [f"| {_escape_pipes(lines[at][3:])} | " + " | ".join(label for _, label in HEADLINE_COLUMNS) + " |",
           "|---|" + "---|" * len(cols)]
    out += [f"| {r[0]} | " + " | ".join(r[c] for c in cols) + " |" for r in rows]
    title = lines[0].lstrip("# ")
    which = "- Data (long): " if table == "c" else "- Data (main): "
    data = next((ln[len(which):].split(": ", 1)[0] for ln in lines if ln.startswith(which)), "")
    reproduce = next((ln for ln in lines if ln.startswith("Reproduce: ")), "")
    out += ["", f"From [{title}]({link}): {data}." + (f" {reproduce}" if reproduce else "")]
    return out


def build_card(source: Path, log_dir: Path, out_path: Path) -> str:
    """The model card to write at `out_path`: `source` (Markdown) with each `<!-- headline ENTRY (x) -->`
    line replaced by `headline_table` of that entry of `log_dir`."""
    import os

    link_base = Path(os.path.relpath(log_dir.resolve(), out_path.resolve().parent)).as_posix() + "/"
    command = shlex.join(["python", "-m", "x2video.eval.card", "--card", source.as_posix(), "--log", log_dir.as_posix(),
                          "--out", out_path.as_posix()])
    out = [f"<!-- Generated by `{command}`: edit {source.as_posix()} (and add to {log_dir.as_posix()}/), not this file. -->", ""]
    for ln in source.read_text(encoding="utf-8").splitlines():
        m = HEADLINE.match(ln.strip())
        if m is None:
            out.append(ln)
            continue
        entry = log_dir / m.group("entry")
        if not entry.is_file():
            raise FileNotFoundError(f"{source}: headline names {entry}, which does not exist")
        out += headline_table(entry, m.group("table"), f"{link_base}{entry.name}")
    return "\n".join(out).rstrip() + "\n"


def _speedup_heading(b: dict[str, Any]) -> str:
    m = b.get("machine", {})
    threads = m.get("torch_threads")
    video = b.get("weights", {}).get("video", {})
    enc = video.get("encoder_dtype")
    where = (f"on {m['cuda']}" if str(m.get("device", "")).startswith("cuda") and m.get("cuda")
             else f"{threads} torch thread{'s' if threads != 1 else ''}")
    distilled = ", channels through the distilled encoder" if video.get("channel_encoder") == "distilled" else ""
    return f"LCM-2 vs DDIM-20 back to back, {where}" + (f", VAE encoder in {enc}" if enc else "") + distilled


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m x2video.eval.card", description=__doc__.split("\n\n")[0])
    p.add_argument("results", nargs="*", type=Path, help="`x2video eval` results folders (or results.json files)")
    p.add_argument("--run", action="append", type=Path, default=[], help="training run folder (repeat: vae, image, video, lcm)")
    p.add_argument("--speedup", action="append", type=Path, default=[],
                   help="bench/lcm_speedup result JSON (repeat): table (d)'s speed-up timed back to back over repeats")
    p.add_argument("--renders", type=Path, help="folder of contact sheets / MP4s (x2video eval --renders N --renders-out DIR)")
    p.add_argument("--preface", type=Path, help="Markdown placed after the header of a report")
    p.add_argument("--out", type=Path, help="write the card or report here (atomically) instead of stdout")
    p.add_argument("--log", type=Path, metavar="DIR", help="add the results and speed-ups to the evaluation log DIR, one dated file each")
    p.add_argument("--card", type=Path, metavar="SOURCE", help="build the model card from SOURCE and the log (--log, default docs/evaluations)")
    a = p.parse_args(argv)
    if a.card is not None and (a.results or a.run or a.speedup or a.renders or a.preface):
        p.error("--card builds the card from its source and the log alone; add results to the log first (--log)")
    if a.log is not None and a.card is None and (a.run or a.renders or a.preface or a.out):
        p.error("--log adds evaluations and speed-ups only")
    if a.card is None and not a.results and not (a.log is not None and a.speedup):
        p.error("give at least one results folder, or --card")
    argv_ = sys.argv[1:] if argv is None else argv
    command = shlex.join(["python", "-m", "x2video.eval.card", *map(str, argv_)])
    try:
        if a.card is not None:
            log_dir = a.log or Path("docs/evaluations")
            a.out = out = a.out or Path("resources/MODEL_CARD.md")
            text = build_card(a.card, log_dir, out)
        else:
            results = [load_results(r) for r in a.results]
            runs = [run_facts(r) for r in a.run]
            speedups = [load_speedup(f) for f in a.speedup]
            if a.log is not None:
                for path in write_log(a.log, results, speedups, command):
                    print(f"wrote {path}")
                return 0
            preface = a.preface.read_text(encoding="utf-8") if a.preface is not None else None
            text = card_markdown(results, runs, a.renders, command, preface, speedups)
    except (ValueError, FileNotFoundError) as e:
        print(f"model card: error: {e}", file=sys.stderr)
        return 2
    if a.out is None:
        sys.stdout.write(text)
    else:
        from x2video.io.atomic import write_text_atomic

        write_text_atomic(a.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
