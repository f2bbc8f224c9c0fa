"""The paper's orderings (issue 5, "Done means") checked on measured numbers: each a claim, whether it holds, and the values."""
from __future__ import annotations

from typing import Any

from x2video.eval.report import cell, scheme_pairs


def _row(results: dict[str, Any], table: str, label: str) -> dict[str, Any] | None:
    for r in results.get("tables", {}).get(table, {}).get("rows", []):
        if r["label"] == label and r.get("available"):
            return r
    return None


def _m(row: dict[str, Any] | None, key: str, side: str = "model") -> float | None:
    v = None if row is None else row[side].get(key)
    return v if isinstance(v, (int, float)) else None


def _holds(a: float, b: float, op: str) -> bool:
    return bool(a < b if op == "<" else a > b if op == ">" else a >= b)


def _check(claim: str, a: float | None, b: float | None, op: str, unit: str = "") -> dict[str, Any]:
    """`a op b`; holds None when a number is missing."""
    if a is None or b is None:
        return {"claim": claim, "holds": None, "values": "not measured"}
    return {"claim": claim, "holds": _holds(a, b, op), "values": f"{a:.5g}{unit} vs {b:.5g}{unit}"}


def _compare(claim: str, ra: dict[str, Any] | None, rb: dict[str, Any] | None, key: str, op: str, unit: str = "",
             side_b: str = "model", scale_a: float = 1.0) -> dict[str, Any]:
    """`_check` of row a's model `key` (times `scale_a`) against row b's (`side_b`: "model", or
    "baseline" for the classical shading), plus how many shots rendered by both agree with the
    ordering ("shots": "3/4"): a mean difference that only some shots share is within noise."""
    a = _m(ra, key)
    out = _check(claim, None if a is None else scale_a * a, _m(rb, key, side_b), op, unit)
    if out["holds"] is None or ra is None or rb is None:
        return out
    sa, sb = ra["model"].get("shots") or {}, rb[side_b].get("shots") or {}
    pairs = [(sa[k].get(key), sb[k].get(key)) for k in sorted(set(sa) & set(sb))]
    pairs = [(scale_a * a, b) for a, b in pairs if isinstance(a, (int, float)) and isinstance(b, (int, float))]
    if pairs:
        out["shots"] = f"{sum(_holds(a, b, op) for a, b in pairs)}/{len(pairs)}"
    return out


def orderings(results: dict[str, Any]) -> list[dict[str, Any]]:
    """Every ordering the model card must show, for the tables present in `results`."""
    out: list[dict[str, Any]] = []
    tables = results.get("tables", {})
    if "a" in tables:
        img, vid = _row(results, "a", "Image model (per frame)"), _row(results, "a", "Video model")
        out.append(_compare("(a) video model TC < image model per frame TC", vid, img, "tc", "<"))
        out.append(_compare("(a) video model PSNR > image model per frame PSNR", vid, img, "psnr", ">", " dB"))
    if "b" in tables:
        full = _row(results, "b", "Full channels")
        for kind in ("Mask A|M|R", "Drop irradiance"):
            base = _row(results, "b", kind)
            out.append(_compare(f"(b) {kind} lowers PSNR below full channels", base, full, "psnr", "<", " dB"))
            for extra in ("Text", "Ref."):
                r = _row(results, "b", f"{kind} + {extra}")
                out.append(_compare(f"(b) {kind} + {extra} recovers PSNR", r, base, "psnr", ">", " dB"))
    if "c" in tables:  # each condition's recursive row against the sequential row of the same condition
        for rec, seq in scheme_pairs([r for r in tables["c"]["rows"] if r.get("available")]):
            suffix = rec["label"][len("Recursive"):]
            out.append(_compare(f"(c) recursive PSNR > sequential PSNR{suffix}", rec, seq, "psnr", ">", " dB"))
            out.append(_compare(f"(c) recursive TC < sequential TC{suffix}", rec, seq, "tc", "<"))
    if "d" in tables:
        rows = [r for r in tables["d"]["rows"] if r.get("available")]

        def _find(sampler: str, reference: bool) -> dict[str, Any] | None:
            return next((r for r in rows if r["settings"]["sampler"] == sampler and bool(r["condition"]["reference"]) == reference), None)

        ddim, lcm = _find("ddim", False), _find("lcm", False)
        out.append(_compare("(d) LCM is >= 5x faster per frame than DDIM (LCM s/frame x 5 <= DDIM s/frame)", lcm, ddim,
                            "seconds_per_frame", "<", scale_a=5))

        def _sampling(r):  # seconds per frame without the channel encoding (denoising + decoding)
            if r is None or "encode_seconds_per_frame" not in r["model"]:
                return None
            return r["model"]["seconds_per_frame"] - r["model"]["encode_seconds_per_frame"]

        ls, ds = _sampling(lcm), _sampling(ddim)
        out.append(_check("(d) ... without the once-per-shot channel encoding (denoise + decode; LCM x 5 <= DDIM)",
                          None if ls is None else 5 * ls, ds, "<"))
        # the paper's own pair (Table "Acceleration": Ref-First 1.20 s vs Ref-First + LCM 2-step 0.24 s; it has
        # no LCM row without a reference, and its No-Ref DDIM 1.08 s is 4.5x that LCM row)
        ddim_r, lcm_r = _find("ddim", True), _find("lcm", True)
        out.append(_compare("(d) ... both with the reference frame (the paper's pair: Ref-First vs Ref-First + LCM 2-step)", lcm_r, ddim_r,
                            "seconds_per_frame", "<", scale_a=5))
    # the classical baseline, on every row that has one
    for key, table in tables.items():
        for r in table["rows"]:
            if not r.get("available"):
                continue
            missing = r["condition"]["kind"] != "full"
            claim = f"({key}) {r['label']}: model PSNR {'>' if missing else '>='} classical baseline PSNR"
            out.append(_compare(claim, r, r, "psnr", ">" if missing else ">=", " dB", side_b="baseline"))
    return out


#: `bench/lcm_speedup.py` ratios and the claim each checks (DDIM-20 s/frame over LCM-2 s/frame)
SPEEDUP_CLAIMS = (
    ("speedup", "(d) LCM is >= 5x faster per frame than DDIM, back to back"),
    ("speedup_no_encoding", "(d) ... without the once-per-shot channel encoding, back to back"),
    ("speedup_ref", "(d) ... both with the reference frame (the paper's pair), back to back"),
)


def speedup_checks(bench: dict[str, Any], factor: float = 5.0) -> list[dict[str, Any]]:
    """The (d) ordering on a `bench/lcm_speedup.py` result: DDIM-20 and LCM-2 timed back to back in
    alternating order over repeats. Holds when the median ratio reaches `factor`; "shots" says in
    how many repeats it does (the repeats play the part the shots play for the tables)."""
    reps = bench.get("repeats") or []
    out = []
    for key, claim in SPEEDUP_CLAIMS:
        vals = [r[key] for r in reps if isinstance(r.get(key), (int, float))]
        if not vals:
            out.append({"claim": claim, "holds": None, "values": "not measured"})
            continue
        med = bench["median"][key]
        out.append({"claim": claim, "holds": bool(med >= factor),
                    "values": f"median {med:.2f}x (min {min(vals):.2f}, max {max(vals):.2f}) vs {factor:g}x",
                    "shots": f"{sum(v >= factor for v in vals)}/{len(vals)} repeats"})
    return out


def orderings_markdown(checks: list[dict[str, Any]]) -> str:
    mark = {True: "yes", False: "**NO**", None: "not measured"}
    lines = ["| ordering | holds | measured | shots that agree |", "|---|---|---|---|"]
    lines += [f"| {cell(c['claim'])} | {mark[c['holds']]} | {c['values']} | {c.get('shots', '')} |" for c in checks]
    return "\n".join(lines)
