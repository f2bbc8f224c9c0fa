"""The paper's orderings (issue 5, "Done means") checked on measured numbers: each a claim, whether it holds, and the values."""
from __future__ import annotations

from typing import Any

from x2video.eval.report import cell


def _row(results: dict[str, Any], table: str, label: str) -> dict[str, Any] | None:
    for r in results.get("tables", {}).get(table, {}).get("rows", []):
        if r["label"] == label and r.get("available"):
            return r
    return None


def _m(row: dict[str, Any] | None, key: str, side: str = "model") -> float | None:
    v = None if row is None else row[side].get(key)
    return v if isinstance(v, (int, float)) else None


def _check(claim: str, a: float | None, b: float | None, op: str, unit: str = "", factor: float = 1.0) -> dict[str, Any]:
    """`a op factor*b`; holds None when a number is missing."""
    if a is None or b is None:
        return {"claim": claim, "holds": None, "values": "not measured"}
    holds = a < factor * b if op == "<" else a > factor * b if op == ">" else a >= factor * b
    return {"claim": claim, "holds": bool(holds), "values": f"{a:.5g}{unit} vs {b:.5g}{unit}"}


def orderings(results: dict[str, Any]) -> list[dict[str, Any]]:
    """Every ordering the model card must show, for the tables present in `results`."""
    out: list[dict[str, Any]] = []
    tables = results.get("tables", {})
    if "a" in tables:
        img, vid = _row(results, "a", "Image model (per frame)"), _row(results, "a", "Video model")
        out.append(_check("(a) video model TC < image model per frame TC", _m(vid, "tc"), _m(img, "tc"), "<"))
        out.append(_check("(a) video model PSNR > image model per frame PSNR", _m(vid, "psnr"), _m(img, "psnr"), ">", " dB"))
    if "b" in tables:
        full = _row(results, "b", "Full channels")
        for kind in ("Mask A|M|R", "Drop irradiance"):
            base = _row(results, "b", kind)
            out.append(_check(f"(b) {kind} lowers PSNR below full channels", _m(base, "psnr"), _m(full, "psnr"), "<", " dB"))
            for extra in ("Text", "Ref."):
                r = _row(results, "b", f"{kind} + {extra}")
                out.append(_check(f"(b) {kind} + {extra} recovers PSNR", _m(r, "psnr"), _m(base, "psnr"), ">", " dB"))
    if "c" in tables:  # each condition's recursive row against the sequential row of the same condition
        rows = [r for r in tables["c"]["rows"] if r.get("available")]
        for rec in (r for r in rows if r["settings"]["scheme"] == "recursive"):
            seq = next((r for r in rows if r["settings"]["scheme"] == "sequential" and r["condition"] == rec["condition"]), None)
            suffix = rec["label"][len("Recursive"):]
            out.append(_check(f"(c) recursive PSNR > sequential PSNR{suffix}", _m(rec, "psnr"), _m(seq, "psnr"), ">", " dB"))
            out.append(_check(f"(c) recursive TC < sequential TC{suffix}", _m(rec, "tc"), _m(seq, "tc"), "<"))
    if "d" in tables:
        rows = [r for r in tables["d"]["rows"] if r.get("available")]
        ddim = next((r for r in rows if r["settings"]["sampler"] == "ddim" and not r["condition"]["reference"]), None)
        lcm = next((r for r in rows if r["settings"]["sampler"] == "lcm" and not r["condition"]["reference"]), None)
        out.append(_check("(d) LCM is >= 5x faster per frame than DDIM (LCM s/frame x 5 <= DDIM s/frame)",
                          None if lcm is None else 5 * lcm["model"]["seconds_per_frame"], _m(ddim, "seconds_per_frame"), "<"))

        def _sampling(r):  # seconds per frame without the channel encoding (denoising + decoding)
            if r is None or "encode_seconds_per_frame" not in r["model"]:
                return None
            return r["model"]["seconds_per_frame"] - r["model"]["encode_seconds_per_frame"]

        ls, ds = _sampling(lcm), _sampling(ddim)
        out.append(_check("(d) ... without the once-per-shot channel encoding (denoise + decode; LCM x 5 <= DDIM)",
                          None if ls is None else 5 * ls, ds, "<"))
    # the classical baseline, on every row that has one
    for key, table in tables.items():
        for r in table["rows"]:
            if not r.get("available"):
                continue
            missing = r["condition"]["kind"] != "full"
            claim = f"({key}) {r['label']}: model PSNR {'>' if missing else '>='} classical baseline PSNR"
            out.append(_check(claim, _m(r, "psnr"), _m(r, "psnr", "baseline"), ">" if missing else ">=", " dB"))
    return out


def orderings_markdown(checks: list[dict[str, Any]]) -> str:
    mark = {True: "yes", False: "**NO**", None: "not measured"}
    lines = ["| ordering | holds | measured |", "|---|---|---|"]
    lines += [f"| {cell(c['claim'])} | {mark[c['holds']]} | {c['values']} |" for c in checks]
    return "\n".join(lines)
