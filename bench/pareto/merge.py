"""Merging runs of bench.pareto into one result (`--merge`): refused unless the run measures the same frames against the
same ground truth; each row names the run that measured it; recursive against sequential sampling compared per section."""
from __future__ import annotations

from pathlib import Path

from bench.pareto.measure import summarise
from x2video.tiers import registry as tiers

#: the keys of a section of the chart: the main section is the result's top level, the others under "sections"
SECTION_KEYS = ("data", "split", "rooms", "frames", "ground_truth", "rows", "unavailable", "summary")
#: a re-scored formula row must agree with the kept one within these (the formula is deterministic: a difference
#: means other frames or another reference)
PROBE_TOLERANCE = {"psnr": 0.02, "ssim": 0.0005, "psnr_dataset": 0.02, "tc": 0.01}


class MergeError(SystemExit):
    """A run that does not measure the same frames against the same ground truth as the result it would merge into."""


def _run_record(res: dict, run_id: int, section: str, origin: Path | None = None) -> dict:
    """What produced some rows: command, commit, date, load, weights, machine (a result of before runs were recorded:
    its date is the commit date of its file, where git knows it)."""
    rec = {"id": run_id, "section": section, "command": res.get("command"), "commit": (res.get("machine") or {}).get("git_commit"),
           "date": res.get("date"), "load_average_start": res.get("load_average_start"), "load_average_end": res.get("load_average_end"),
           "wall_seconds": res.get("wall_seconds"), "weights": res.get("weights"), "weights_sha256": res.get("weights_sha256"),
           "threads": res.get("threads"), "clock": res.get("clock"), "complete": res.get("complete", True), "machine": res.get("machine"),
           "methods": list(dict.fromkeys(r["method"] for r in res.get("rows", []))),
           "engines": sorted({r["engine"] for r in res.get("rows", []) if r.get("engine")}) or None}
    if rec["date"] is None and origin is not None:
        rec["date"], rec["date_note"] = _commit_date(origin), f"not recorded by the run: the last commit date of {origin.name}"
    return rec


def _commit_date(path: Path) -> str | None:
    import subprocess

    try:
        out = subprocess.run(["git", "log", "-1", "--format=%cI", "--", path.name], cwd=path.parent, capture_output=True, text=True, timeout=30)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def section_of(res: dict, name: str) -> dict | None:
    if not name:
        return {k: res.get(k) for k in SECTION_KEYS} if res.get("rows") is not None else None
    return (res.get("sections") or {}).get(name)


def _shots_of(sec: dict, size: str) -> tuple[list[str], list[int]]:
    """(shot names, frames per shot) a section measured at `size`: recorded in its ground truth, or (results from
    before that was recorded) read off its rows."""
    g = (sec.get("ground_truth") or {}).get(size) or {}
    if "shots" in g:
        return list(g["shots"]), list(g["frames"])
    for r in sec.get("rows") or []:
        if f"{r['size'][0]}x{r['size'][1]}" == size and r.get("per_shot"):
            return [p["shot"] for p in r["per_shot"]], [p["frames"] for p in r["per_shot"]]
    return [], []


def merge_problems(old: dict, new: dict, section: str, where: str = "the result merged into") -> tuple[list[str], dict[str, str]]:
    """Why `new` (a run of this bench) cannot be merged into section `section` of `old` (empty: it can), and per size how
    the ground truth was found the same. Checked: clock and threads; data folders and split; per size measured by both,
    the shots, their frames, the ground truth's kind, samples and seed, the digest of the inputs and the data set's
    frames (where both recorded it), and the reference: its digest, else a re-scored formula row against the kept one."""
    problems: list[str] = []
    checks: dict[str, str] = {}
    for key in ("clock", "threads"):
        if old.get(key) != new.get(key):
            problems.append(f"--{key}: this run has {new.get(key)!r}, {where} {old.get(key)!r} (its seconds would not compare)")
    o, n = section_of(old, section), section_of(new, "")
    if o is None or n is None:
        return problems, checks
    if sorted(o.get("data") or []) != sorted(n.get("data") or []) or o.get("split") != n.get("split"):
        problems.append(f"--data/--split: this run read {n.get('data')} ({n.get('split')!r}), {where} {o.get('data')} ({o.get('split')!r})")
    old_sizes = set(o.get("ground_truth") or {}) | {f"{r['size'][0]}x{r['size'][1]}" for r in o.get("rows") or []}
    for size, g in (n.get("ground_truth") or {}).items():
        if size not in old_sizes:
            checks[size] = "a size of its own (nothing to compare)"
            continue
        og = (o.get("ground_truth") or {}).get(size) or {}
        (oshots, oframes), (nshots, nframes) = _shots_of(o, size), _shots_of(n, size)
        if (oshots, oframes) != (nshots, nframes):
            problems.append(f"{size}: this run measured shots {nshots} at frames {nframes}, {where} {oshots} at {oframes} (--rooms/--frames)")
        for key in ("kind", "samples", "seed"):
            if og.get(key) != g.get(key):
                problems.append(f"{size}: ground truth {key} {g.get(key)!r}, {where} {og.get(key)!r} (--reference-samples)")
        if og.get("data_sha256") and g.get("data_sha256") and og["data_sha256"] != g["data_sha256"]:
            problems.append(f"{size}: the same shot names hold other frames (digest of the channels and rgb differs): the data set was rebuilt")
        if "reference_sha256" not in g or problems:
            continue
        if og.get("reference_sha256") == g["reference_sha256"]:
            checks[size] = "reference and data digests equal to the kept rows'" if og.get("data_sha256") == g.get("data_sha256") \
                else "reference digest equal to the kept rows'"
            continue
        new_rows = [r for r in n.get("rows") or [] if f"{r['size'][0]}x{r['size'][1]}" == size]
        if not new_rows:
            continue  # nothing measured yet at this size: checked with its first row
        nf = next((r for r in new_rows if r["method"] == tiers.FORMULA), None)
        of = next((r for r in o.get("rows") or [] if r["method"] == tiers.FORMULA and f"{r['size'][0]}x{r['size'][1]}" == size), None)
        if nf is None or of is None:
            problems.append(f"{size}: cannot check that this run's reference is the kept rows' ("
                            + ("no reference digest in " + where if not og.get("reference_sha256") else "its digest differs")
                            + "): add formula to --methods (a deterministic row to re-score)" + (f"; {where} has none" if of is None else ""))
            continue
        off = {k: (nf.get(k), of.get(k)) for k, tol in PROBE_TOLERANCE.items()
               if nf.get(k) is not None and of.get(k) is not None
               and abs(nf[k] - of[k]) > (tol * abs(of[k]) if k == "tc" else tol)}
        if off:
            problems.append(f"{size}: the formula row re-scored against this run's reference differs from the kept one ("
                            + ", ".join(f"{k} {a:.5g} vs {b:.5g}" for k, (a, b) in off.items())
                            + "): another reference or other frames")
        else:
            checks[size] = (f"formula row re-scored: PSNR {nf['psnr']:.5f} vs {of['psnr']:.5f} kept, TC {nf['tc']} vs {of['tc']}, "
                            f"PSNR vs data set {nf['psnr_dataset']:.5f} vs {of['psnr_dataset']:.5f}")
    return problems, checks


def _row_order(r: dict) -> tuple:
    # the built-in tiers in cost order, tiers registered later, then Cycles
    kinds = [*tiers.QUALITIES[1:], *(q for q in tiers.qualities()[1:] if q not in tiers.QUALITIES), "cycles"]
    return (r["size"][0] * r["size"][1], kinds.index(r["kind"]) if r["kind"] in kinds else 9, r.get("scheme") == "sequential", r.get("sampler") or "",
            r.get("steps") or 0, r.get("samples") or 0)


def merge(old: dict, new: dict, section: str = "", origin: Path | None = None, merged_with: str | None = None) -> dict:
    """`old` with `new`'s rows: in section `section` ('' the main one), a row of `new` replaces the row of the same
    method and size, the others are kept; each row names its run (`runs`; `merged_with`: the command that merged a
    finished result). MergeError when `merge_problems`."""
    where = str(origin) if origin is not None else "the result merged into"
    if old.get("format") != "x2video-pareto":
        raise MergeError(f"--merge {where}: not a bench.pareto result (format {old.get('format')!r})")
    problems, checks = merge_problems(old, new, section, where)
    if problems:
        raise MergeError(f"--merge {where}{f' (section {section!r})' if section else ''}: this run does not measure what it holds:\n  - "
                         + "\n  - ".join(problems))
    out = {k: v for k, v in old.items() if k not in ("runs",)}
    runs = [dict(r) for r in old.get("runs") or []]
    if not runs:  # a result from before runs were recorded: one run made all its rows
        runs = [_run_record(old, 1, "", origin)]
        out["rows"] = [{**r, "run": 1} for r in old.get("rows") or []]
    run_id = max(r["id"] for r in runs) + 1
    rec = _run_record(new, run_id, section)
    rec["merge_checks"] = checks
    if merged_with:
        rec["merged_with"] = merged_with
    runs.append(rec)
    n = section_of(new, "")
    o = section_of(out, section) or {"data": n["data"], "split": n["split"], "rooms": {}, "frames": {}, "ground_truth": {}, "rows": [],
                                   "unavailable": []}
    measured = {(r["method"], tuple(r["size"])) for r in n["rows"]} | {(u["method"], tuple(u["size"])) for u in n["unavailable"]}
    rows = [r for r in o["rows"] if (r["method"], tuple(r["size"])) not in measured] + [{**r, "run": run_id} for r in n["rows"]]
    merged = {"data": o["data"], "split": o["split"], "rooms": {**o["rooms"], **n["rooms"]}, "frames": {**o["frames"], **n["frames"]},
              "ground_truth": {**o["ground_truth"], **n["ground_truth"]}, "rows": sorted(rows, key=_row_order),
              "unavailable": [u for u in o["unavailable"] if (u["method"], tuple(u["size"])) not in measured] + list(n["unavailable"])}
    merged["summary"] = summarise(merged["rows"])
    if section:
        merged["schemes"] = compare_schemes(merged["rows"])
        out["sections"] = {**(old.get("sections") or {}), section: merged}
    else:
        out.update(merged)
    for key in ("command", "date", "machine", "load_average_start", "load_average_end", "weights", "weights_sha256", "residual_net", "has_lcm",
                "wall_seconds"):
        if key in new:
            out[key] = new[key]  # the latest run's (each run's own: `runs`)
    if merged_with:
        out["command"] = merged_with  # what wrote this file
    out["summary"] = summarise(out["rows"])  # derived: recomputed for every section (the code may have changed since)
    for sec in (out.get("sections") or {}).values():
        sec["summary"], sec["schemes"] = summarise(sec["rows"]), compare_schemes(sec["rows"])
    out["complete"] = bool(old.get("complete", True)) and bool(new.get("complete", True))
    out["runs"] = runs
    return out


def compare_schemes(rows: list[dict]) -> list[dict]:
    """Per size and sampler-steps measured both ways: recursive against sequential sampling (PSNR, TC, CPU and wall seconds)."""
    out = []
    for r in rows:
        if not tiers.windowed(r["kind"]) or r.get("scheme") != "recursive":
            continue
        q = next((x for x in rows if x["method"] == r["method"] + "-seq" and x["size"] == r["size"]), None)
        if q is not None:
            out.append({"size": r["size"], "setting": r["method"], **{f"{k}_{s}": x.get(k) for s, x in (("recursive", r), ("sequential", q))
                                                                      for k in ("psnr", "tc", "cpu_seconds_per_frame", "wall_seconds_per_frame")}})
    return out
