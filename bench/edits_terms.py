"""What limits an albedo edit rebuilt from the passes: each term of Cycles' re-render swapped into the rebuild in turn.

Cycles splits its Combined as DiffCol x (DiffDir + DiffInd) + GlossCol x (GlossDir + GlossInd) + Emit + Env (+ the
denoiser's difference between the whole and the sum of its separately denoised passes). The compositor's rebuild of
an albedo edit, the floor x2video's tier 0 keeps (`x2video.base.passes`), is

    rebuild = Combined - DiffCol x L + colour' x L,   L = DiffDir + DiffInd of the shot as it was.

Here, on each room's albedo pair of `bench.edits_data` (the shot, and Cycles' re-render of the edit with the same seed),
the rebuild is scored inside the edited object beside the shot as it was, the formula (the new colour times the
shot's irradiance, DiffDir + DiffInd) and oracles that take one term from the re-render: its diffuse
colour, its diffuse light, its glossy term, all of them; and beside the light taken from the denoised Combined
((Combined - glossy - emission) / DiffCol where the diffuse term is over 90 % of the pixel's light) instead of the
separately denoised light passes. The error inside is split between the object's metallic pixels (metallic > 0.5)
and the rest. PSNR on display images (`x2video.channels.tonemap`), squared error pooled over a room's frames, as
`bench.edits` scores.

    python -m bench.edits_terms [--seeds S1,S2] [--size 320x224]

Writes bench/results/edits/edits_terms.json. The rooms are `bench.edits_data`'s (validation and test, marked).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from bench.clips import TEST_SEEDS
from bench.common import clean_json, command, results_path
from bench.edits import read_passes
from bench.edits_data import EDITS_VALIDATION_SEEDS, default_root
from x2video.channels import tonemap
from x2video.eval.machine import machine_info
from x2video.fields import parse_size

NAMES = ("Combined", "DiffCol", "DiffDir", "DiffInd", "GlossCol", "GlossDir", "GlossInd", "Emit", "Env")
#: the diffuse term's share of a pixel's light above which the Combined-derived light is used
DIFFUSE_SHARE = 0.9


def variants(b: dict, a: dict, colour: np.ndarray) -> dict[str, np.ndarray]:
    """Each estimate of the re-render `a` made from the shot's passes `b` and the new `colour` (see the docstring)."""
    light = lambda p: p["DiffDir"] + p["DiffInd"]  # noqa: E731
    gloss = lambda p: p["GlossCol"] * (p["GlossDir"] + p["GlossInd"])  # noqa: E731
    rest = b["Combined"] - b["DiffCol"] * light(b) - gloss(b)  # emission, environment and the denoiser's difference
    emit = b["Emit"] + b["Env"]
    diffuse = b["DiffCol"] * light(b)
    from_combined = np.maximum(b["Combined"] - gloss(b) - emit, 0) / np.maximum(b["DiffCol"], 1e-4)
    use = (diffuse / np.maximum(diffuse + gloss(b) + emit, 1e-6) > DIFFUSE_SHARE) & (b["DiffCol"] > 0.02)
    return {"the shot as it was (no edit)": b["Combined"],
            "the formula (colour' x irradiance)": colour * light(b),
            "rebuild from passes (the floor)": rest + colour * light(b) + gloss(b),
            "oracle: re-render's diffuse colour": rest + a["DiffCol"] * light(b) + gloss(b),
            "oracle: re-render's diffuse light": rest + colour * light(a) + gloss(b),
            "oracle: re-render's glossy term": rest + colour * light(b) + gloss(a),
            "oracle: re-render's colour, diffuse light and glossy term": rest + a["DiffCol"] * light(a) + gloss(a),
            "light from the denoised Combined": np.where(use, b["Combined"] + (colour - b["DiffCol"]) * from_combined,
                                                         rest + colour * light(b) + gloss(b))}


def score_room(folder: Path) -> dict | None:
    from x2video.io.load import load_shot

    after = folder / "after_albedo"
    if not (after / "edits.json").is_file():
        return None
    doc = json.loads((after / "edits.json").read_text())
    tid, colour = int(doc["target"]["id"]), np.float32(doc["look"]["color"])
    shot = load_shot(folder / "before")
    err: dict[str, list[float]] = {}
    split = {"metal": [0.0, 0], "other": [0.0, 0]}
    for t in range(shot.num_frames):
        b = read_passes(folder / "before" / f"frame_{t:04d}.exr", NAMES)
        a = read_passes(after / f"frame_{t:04d}.exr", NAMES)
        inside = shot.channel("ids", t)[..., 0] == tid
        metal = shot.channel("metallic", t)[..., 0] > 0.5
        truth = tonemap(a["Combined"])
        for name, v in variants(b, a, colour).items():
            e = ((tonemap(v) - truth) ** 2).mean(-1)
            err.setdefault(name, []).append(float(e[inside].sum()))
            if name.startswith("rebuild"):
                for part, sel in (("metal", inside & metal), ("other", inside & ~metal)):
                    split[part][0] += float(e[sel].sum())
                    split[part][1] += int(sel.sum())
        err.setdefault("_pixels", []).append(float(inside.sum()))
    n = sum(err.pop("_pixels"))
    total = split["metal"][0] + split["other"][0]
    return {"room": folder.name, "object": doc["target"].get("caption"), "colour": [float(c) for c in colour],
            "psnr_inside": {k: 10 * np.log10(n / max(sum(v), 1e-12)) for k, v in err.items()},
            "metallic_pixels_share": split["metal"][1] / max(n, 1),
            "rebuild_error_share_on_metallic_pixels": split["metal"][0] / max(total, 1e-12)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default=f"{EDITS_VALIDATION_SEEDS},{TEST_SEEDS}")
    ap.add_argument("--size", default="320x224")
    args = ap.parse_args(argv)
    root = default_root(*parse_size(args.size))
    val = set(EDITS_VALIDATION_SEEDS.split(","))
    rooms = []
    for s in args.seeds.split(","):
        r = score_room(root / f"room_{s}")
        if r is None:
            print(f"room_{s}: no albedo pair under {root} (python -m bench.edits_data --seeds {s})", file=sys.stderr)
            continue
        r["split"] = "validation" if s in val else "test"
        rooms.append(r)
        print(f"{r['room']} ({r['split']}, {r['object']}): " + "; ".join(f"{k} {v:.2f}" for k, v in r["psnr_inside"].items())
              + f"; metallic pixels {100 * r['metallic_pixels_share']:.0f}% of the object, "
              f"{100 * r['rebuild_error_share_on_metallic_pixels']:.0f}% of the rebuild's error", flush=True)
    out = {"bench": "edits_terms", "description": __doc__.splitlines()[0], "command": command("edits_terms", argv),
           "size": args.size, "machine": machine_info(), "diffuse_share": DIFFUSE_SHARE, "rooms": rooms}
    path = results_path("edits", "edits_terms")
    path.write_text(json.dumps(clean_json(out), indent=1))
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
