"""Composes resources/MODEL_CARD.md from `x2video eval` results folders and training run folders (issue 5, "Done means").

    python -m x2video.eval.card RESULTS_DIR [RESULTS_DIR ...] [--run RUN_DIR ...] [--speedup LCM_SPEEDUP_JSON ...]
        [--renders DIR] [--out resources/MODEL_CARD.md]
    python -m x2video.eval.card RESULTS_DIR [...] [--speedup JSON ...] [--preface MD] --append resources/MODEL_CARD.md

Every number in the card is read from a results.json (with the exact command that produced
it) or from a training run's state.json / summary.json / log.json / results.json; nothing is
typed in by hand. Without --out the card goes to stdout.

`--append CARD` adds evaluations and speed-up sections to an existing card instead, numbered on
from its last "Evaluation k" and placed before its renders, and (with --preface) replaces its
preface; the rest of the card, built from results and runs a later session may no longer have,
is kept as it is. The card's header then names both commands.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import shlex
import sys
from pathlib import Path
from typing import Any

from x2video.eval.checks import orderings, orderings_markdown, speedup_checks
from x2video.eval.report import results_markdown


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


RENDERS_HEADING = "## Renders of held-out shots"


def append_to_card(card: str, results: list[dict[str, Any]], speedups: list[dict[str, Any]], command: str,
                   preface: str | None = None) -> str:
    """`card` with `results` and `speedups` appended as `card_markdown` would write them (see the module docstring)."""
    lines = card.splitlines()
    if not lines or lines[0] != "# X2Video model card":
        raise ValueError("not a model card written by x2video.eval.card (its first line is not '# X2Video model card')")
    gen = next((i for i, ln in enumerate(lines) if ln.startswith("Generated ")), None)
    if gen is None:
        raise ValueError("the model card has no 'Generated ...' line")
    numbers = [int(ln.split()[-1]) for ln in lines if ln.startswith("## Evaluation ") and ln.split()[-1].isdigit()]
    first = max(numbers, default=1 if any(ln == "## Evaluation" for ln in lines) else 0) + 1
    new: list[str] = []
    for i, r in enumerate(results):
        new.append(results_markdown(r, heading=f"Evaluation {first + i}"))
        new += ["### Orderings the paper reports, on these numbers", "", orderings_markdown(orderings(r)), ""]
    for b in speedups:
        new.append(speedup_markdown(b, _speedup_heading(b)))
    at = next((i for i, ln in enumerate(lines) if ln.startswith(RENDERS_HEADING)), len(lines))
    lines = lines[:at] + "\n".join(new).splitlines() + [""] * bool(new) + lines[at:]
    if not new:  # one line says who wrote the current preface
        lines = [ln for ln in lines if not ln.startswith("Preface replaced ")]
    lines.insert(gen + 1, f"{'Sections appended' if new else 'Preface replaced'} {_dt.date.today().isoformat()} by `{command}`.")
    if preface is not None:
        start = gen + 2
        while start < len(lines) and lines[start].startswith(("Sections appended ", "Preface replaced ")):
            start += 1
        end = next((i for i, ln in enumerate(lines) if i > start and (ln == "## Training" or ln.startswith("## Evaluation"))), None)
        if end is None:
            raise ValueError("the model card has no '## Training' or '## Evaluation' section to keep after the preface")
        lines = lines[:start] + ["", *preface.strip().splitlines(), ""] + lines[end:]
    return "\n".join(lines) + "\n"


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
    p.add_argument("results", nargs="*", type=Path, help="`x2video eval` results folders (or results.json files); none only "
                                                          "with --append (e.g. to replace the preface)")
    p.add_argument("--run", action="append", type=Path, default=[], help="training run folder (repeat: vae, image, video, lcm)")
    p.add_argument("--speedup", action="append", type=Path, default=[],
                   help="bench/lcm_speedup.py result JSON (repeat): table (d)'s speed-up timed back to back over repeats")
    p.add_argument("--renders", type=Path, help="folder of contact sheets / MP4s (x2video eval --renders N --renders-out DIR)")
    p.add_argument("--preface", type=Path, help="Markdown placed after the header (data recipe, how to read the card)")
    p.add_argument("--out", type=Path, help="write the card here (atomically) instead of stdout")
    p.add_argument("--append", type=Path, metavar="CARD",
                   help="add these evaluations and speed-ups to the existing card CARD (rewritten in place unless --out)")
    a = p.parse_args(argv)
    if a.append is not None and (a.run or a.renders):
        p.error("--append adds evaluations and speed-ups only; --run and --renders need a whole new card")
    if not a.results and a.append is None:
        p.error("give at least one results folder")
    try:
        results = [load_results(r) for r in a.results]
        runs = [run_facts(r) for r in a.run]
        speedups = [load_speedup(f) for f in a.speedup]
    except (ValueError, FileNotFoundError) as e:
        print(f"model card: error: {e}", file=sys.stderr)
        return 2
    argv_ = sys.argv[1:] if argv is None else argv
    preface = a.preface.read_text(encoding="utf-8") if a.preface is not None else None
    command = shlex.join(["python", "-m", "x2video.eval.card", *map(str, argv_)])
    if a.append is not None:
        try:
            text = append_to_card(a.append.read_text(encoding="utf-8"), results, speedups, command, preface)
        except (ValueError, FileNotFoundError) as e:
            print(f"model card: error: {a.append}: {e}", file=sys.stderr)
            return 2
        a.out = a.out or a.append
    else:
        text = card_markdown(results, runs, a.renders, command, preface, speedups)
    if a.out is None:
        sys.stdout.write(text)
    else:
        from x2video.io.atomic import write_text_atomic

        write_text_atomic(a.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
