"""Edits over path-traced frames (issue 52 item 5): each look-dev change made by every method, scored against Cycles'
re-render of the same change.

On the rooms of `bench.edits_data` (Cycles before and after one change, same light gain, seed and samples), for each
edit kind and method, on the same frames: PSNR on display images (`x2video.channels.tonemap`; a renderer's frames
divided by the shot's irradiance_scale, as `bench.ptscore` does) against Cycles' after render, inside the edited
object (its ids), in a `BAND`-px band around it, outside both, and over the whole frame (the light edit reaches the
whole frame: its inside is the frame), each the PSNR of the squared error pooled over the room's frames, averaged
over rooms; and seconds per edited frame beside Cycles' re-render seconds. Methods:

- ``nothing``: the frames as they were (the before render);
- ``rebuild``: a compositor's rebuild from the before render's passes: albedo edits
  ``Combined - DiffCol x (DiffDir + DiffInd) + colour x (DiffDir + DiffInd)`` inside the object; the light edit
  every pass times the tint (a grade of the whole frame, exact when every light changes together); metallic edits
  ``Combined - DiffCol x DiffLight - GlossCol x GlossLight + DiffCol' x DiffLight + GlossCol' x GlossLight`` with
  ``DiffCol' = albedo x (1 - m)`` and ``GlossCol' = 0.04 x (1 - m) + albedo x m`` (m the new metallic; the light of
  a pure metal's black diffuse passes unknown, so left black); roughness edits: no pass holds them, so the same as
  doing nothing;
- ``off``: x2video re-rendering the frames from the edited channels (RenderSettings ``base="off"``, quality auto:
  what every render did before the base existed);
- ``base-formula``, ``base-residual``, ``base-auto``: x2video with the shot's rgb as the base (``base="auto"``) and
  that quality: the edit's change over the base inside its reach (`x2video.base.stage`): R(edited) against
  R(original), R tier 0's rebuild from the passes (`x2video.base.passes`) or tier 1's frame, as a ratio where only
  the light changed and a difference elsewhere (`x2video.base.difference.LIGHT_MODE`, `MATERIAL_MODE`);
- ``base-ratio``, ``base-difference``: base x R(edited) / R(original), or base + R(edited) - R(original), everywhere
  (`edited_frame`'s mode), tier 1 where roughness, metallic or normal changed and the formula elsewhere, as
  base-auto chooses: what the per-kind choice is measured against;
- ``base-sharpen``: base-auto with tier 1's difference also where a surface was only made glossier
  (`x2video.base.difference.sharpened` keeps the formula's there): what that rule is measured against;
- ``base-auto-replace``: base-auto with a generating tier's frame replacing the base inside the reach, where base-auto
  adds it as a difference (the frame minus tier 1's of the unedited channels, `x2video.base.stage.GeneratedOver`):
  scored on the kind the diffusion tier renders (``masked``) only, the others' frames being base-auto's.

Kinds: those rendered by `bench.edits_data`, and ``masked`` (`bench.edits_masked`): the albedo pair again, the object's
A|M|R masked out and a local prompt naming the colour, which the diffusion tier generates; its rebuild is the albedo
kind's. Object kinds also get the seam statistic at the edge of the edit's reach (`bench.edits_masked.Seam`), the
truth's beside each method's.

Where `RenderSettings` has no ``base`` field (a build before the Renderer took the base), the base rows are computed
from the same library pieces the Renderer calls (`x2video.base.stage.edited_frame`) and say so (``via``).

    python -m bench.edits_data                 # the rooms first (validation and test; resumable)
    python -m bench.edits [--root DIR] [--seeds 43000130,43000131 | --validation] [--kinds ...] [--methods ...]

Writes bench/results/edits/edits.json, edits.md (its tables) and edits.png (`--picture KIND:METHOD`: the first room's
middle frame as rendered, after the edit by x2video, and by Cycles, with seconds and PSNR); test rooms, or with
--validation edits_validation.*.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.clips import TEST_SEEDS
from bench.common import clean_json, command, results_path
from bench.edits_data import EDITS_VALIDATION_SEEDS, default_root
from bench.edits_data import KINDS as RENDERED
from bench.edits_masked import KIND as MASKED
from x2video.fields import parse_size

#: pixels around the edited object scored as its band (the spill margin of `x2video.base.difference`)
BAND = 6
#: the kinds scored: each rendered one, and the masked kind on the albedo pair (`bench.edits_masked`)
KINDS = (*RENDERED, MASKED)
METHODS = ("nothing", "rebuild", "off", "base-formula", "base-residual", "base-auto", "base-ratio", "base-difference", "base-sharpen",
           "base-auto-replace")
REGIONS = ("inside", "band", "outside", "whole")
#: methods that need the model (tier 1 or the Renderer's choice)
NEEDS_MODEL = ("off", "base-residual", "base-auto", "base-ratio", "base-difference", "base-sharpen", "base-auto-replace")
#: methods the Renderer runs with an option (`Renderer.render`'s keywords)
RENDER_OPTIONS = {"base-auto-replace": {"generated": "replace"}}
#: methods made from the library pieces (`library_frames`: an `edited_frame` option the Renderer does not take)
LIBRARY = {"base-ratio": {"mode": "ratio"}, "base-difference": {"mode": "difference"}, "base-sharpen": {"sharpen": True}}


# ---------------------------------------------------------------------------------------------- scoring
def regions(inside: np.ndarray, band: int = BAND) -> dict[str, np.ndarray]:
    """The four scored regions of one frame, (H, W) bool each, from the edited object's pixels."""
    from x2video.base.difference import grow

    near = grow(inside, band)
    whole = np.ones_like(inside, bool)
    return {"inside": inside, "band": near & ~inside, "outside": ~near, "whole": whole}


class Scores:
    """Squared errors and pixel counts per region, pooled over frames; `psnr` per region (None where empty)."""

    def __init__(self) -> None:
        self.sse = dict.fromkeys(REGIONS, 0.0)
        self.n = dict.fromkeys(REGIONS, 0)

    def add(self, pred: np.ndarray, gt: np.ndarray, masks: dict[str, np.ndarray]) -> None:
        err = ((pred.astype(np.float64) - gt.astype(np.float64)) ** 2).sum(-1)  # (H, W)
        for r, m in masks.items():
            self.sse[r] += float(err[m].sum())
            self.n[r] += int(m.sum()) * pred.shape[-1]

    def psnr(self) -> dict[str, float | None]:
        out: dict[str, float | None] = {}
        for r in REGIONS:
            if self.n[r] == 0:
                out[r] = None
            else:
                mse = self.sse[r] / self.n[r]
                out[r] = 99.0 if mse == 0 else 10 * np.log10(1 / mse)
        return out


# ---------------------------------------------------------------------------------------------- methods
def read_passes(path: Path, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """(H, W, 3) float32 of each named Cycles pass of a multi-layer frame."""
    from x2video.io.image import read_image
    from x2video.io.multilayer import group_passes

    img = read_image(path)
    layers = group_passes(tuple(img.channel_names))
    out = {}
    for name in names:
        layer = next((lay for lay, passes in layers.items() if name in passes), None)
        if layer is None:
            raise ValueError(f"{path}: no {name} pass (the rebuild from passes needs DiffCol, DiffDir and DiffInd)")
        comps = layers[layer][name]
        out[name] = img.stack([comps[c] for c in "RGB"]).astype(np.float32)
    return out


def rebuild(before: Any, look: dict, t: int, inside: np.ndarray) -> np.ndarray:
    """The compositor's rebuild of frame t in the shot's units (see the module docstring)."""
    rgb = before.channel("rgb", t).astype(np.float32)
    if look["kind"] == "light":
        return rgb * float(look["scale"]) * np.asarray(look["tint"], np.float32)
    frame = sorted(Path(before.info.source).glob("frame_*.exr"))[t]
    if look["kind"] in ("metal_off", "metal_on"):
        from x2video.base.passes import DIELECTRIC_GLOSS

        p = read_passes(frame, ("DiffCol", "DiffDir", "DiffInd", "GlossCol", "GlossDir", "GlossInd"))
        m = np.float32(look["value"])
        albedo = np.clip(before.channel("albedo", t), 0, 1)
        diff, gloss = p["DiffDir"] + p["DiffInd"], p["GlossDir"] + p["GlossInd"]
        new = (rgb - p["DiffCol"] * diff - p["GlossCol"] * gloss + albedo * (1 - m) * diff
               + (np.float32(DIELECTRIC_GLOSS) * (1 - m) + albedo * m) * gloss)
        return np.where(inside[..., None], np.maximum(new, 0), rgb)
    if look["kind"] not in ("albedo", MASKED):
        return rgb
    p = read_passes(frame, ("DiffCol", "DiffDir", "DiffInd"))
    light = p["DiffDir"] + p["DiffInd"]
    new = rgb - p["DiffCol"] * light + np.asarray(look["color"], np.float32) * light
    return np.where(inside[..., None], np.maximum(new, 0), rgb)


def has_base_field() -> bool:
    """Whether `RenderSettings` takes ``base`` (the Renderer renders edits over the shot's rgb)."""
    from x2video.render.settings import RenderSettings

    return any(f.name == "base" for f in dataclasses.fields(RenderSettings))


def settings_for(method: str, frames: tuple[int, int] | None = None) -> Any:
    from x2video.render.settings import RenderSettings

    quality = {"off": "auto", "base-formula": "formula", "base-residual": "residual", "base-auto": "auto", "base-auto-replace": "auto"}[method]
    base = {} if not has_base_field() else {"base": "off" if method == "off" else "auto"}
    return RenderSettings(quality=quality, frames=frames, **base)


def renderer_frames(renderer: Any, shot: Any, edits: Any, method: str) -> tuple[list[np.ndarray], float]:
    """(the Renderer's frames of `method` in the shot's units, seconds per frame), warmed on two frames first."""
    from bench.ptscore import render_timed

    options = RENDER_OPTIONS.get(method, {})
    renderer.render(shot, edits, settings_for(method, (0, min(2, shot.num_frames))), **options)  # graphs, text encoder: off the clock
    renderer.cache.clear()
    frames, secs = render_timed(renderer, shot, settings_for(method), edits, **options)
    scale = float(shot.info.irradiance_scale)
    return [np.asarray(f, np.float64) / scale for f in frames], secs / shot.num_frames


def library_frames(model: Any, shot: Any, edits: Any, method: str) -> tuple[list[np.ndarray], float]:
    """(frames of a base method made from the library pieces (`x2video.base.stage.edited_frame` with `LIBRARY`'s
    options, tier 1 where base-auto would run it), in the shot's units; seconds per frame)."""
    from x2video.base import stage
    from x2video.conditioning.edited import apply_edits
    from x2video.conditioning.frame import plain_conditioning

    residual = None
    if method in NEEDS_MODEL and model is not None and model.residual_net is not None:
        from x2video.base.tier1 import residual_difference

        def residual(edited, original, wanted):  # noqa: E306  # as the Renderer's tier 1 runs it (the box around the edit)
            return residual_difference(model.residual_net, original, edited, wanted, device=model.device)

    scale = float(shot.info.irradiance_scale)
    out, t0 = [], time.perf_counter()
    for t in range(shot.num_frames):
        base = shot.channel("rgb", t).astype(np.float64) * scale
        original, edited = plain_conditioning(shot, t), apply_edits(shot, edits, t)
        frame = stage.edited_frame(base, original, edited, glossy_tier=residual is not None, residual=residual, **LIBRARY.get(method, {}))[0]
        out.append(np.asarray(frame, np.float64) / scale)
    return out, (time.perf_counter() - t0) / shot.num_frames


# ---------------------------------------------------------------------------------------------- one room
def edit_pair(folder: Path, kind: str) -> tuple[Path, Path, dict] | None:
    """(the shot edited, Cycles' render of the edit, the edit's record) of `kind` in a room, or None where the room has
    none. A room with no metal to make non-metal scores ``metal_off`` on the ``metal_on`` pair reversed: the object
    Cycles rendered as metal is the shot, made non-metal again (metallic set to its value in the before render), and the
    before render, made with the same seed and samples, is the truth."""
    if kind == MASKED:
        from bench.edits_masked import masked_pair

        return masked_pair(folder)
    after_dir = folder / f"after_{kind}"
    if (after_dir / "edits.json").is_file():
        return folder / "before", after_dir, json.loads((after_dir / "edits.json").read_text())
    on = folder / "after_metal_on" / "edits.json"
    if kind != "metal_off" or not on.is_file():
        return None
    from bench.edits_data import frame_seconds, x2video_edits
    from x2video.io.load import load_shot

    doc = json.loads(on.read_text())
    target = doc["target"]
    before = load_shot(folder / "before")
    obj = np.isin(before.channel("ids", 0)[..., 0], [int(target["id"])])
    value = float(np.median(before.channel("metallic", 0)[..., 0][obj])) if obj.any() else 0.0
    look = {"kind": "metal_off", "id": int(target["id"]), "value": value}
    secs = frame_seconds(folder / "before")  # Cycles' seconds of the truth: its picture alone where timed, else with passes
    spf = float(np.mean(secs["beauty"] or secs["frames"])) if secs["beauty"] or secs["frames"] else None
    rec = {"kind": "metal_off", "target": target, "look": look, "edits": x2video_edits(look),
           "cycles": {**doc["cycles"], "seconds_per_frame": spf, "passes_seconds_per_frame": None},
           "reversed": "the metal_on pair reversed: after_metal_on is the shot, before/ the truth",
           "source": str(on)}
    return folder / "after_metal_on", folder / "before", rec


def score_room(folder: Path, kinds: tuple[str, ...], methods: tuple[str, ...], model: Any, log=print,
               keep: dict | None = None) -> list[dict]:
    """Rows {kind, seed, target, cycles_seconds_per_frame, methods: {m: {regions..., seconds_per_frame, via}}} of one room;
    `keep`, when given, gets each method's display image of the middle frame under (kind, method) ("cycles": the truth)."""
    from bench.edits_masked import rings, seam
    from x2video.base.difference import grow
    from x2video.channels import tonemap
    from x2video.edits.model import Edits
    from x2video.io.load import load_shot
    from x2video.render.renderer import Renderer

    renderer = Renderer(model) if model is not None else Renderer(None)
    base_field = has_base_field()
    rows = []
    for kind in kinds:
        pair = edit_pair(folder, kind)
        if pair is None:
            continue
        before_dir, after_dir, doc = pair
        before, after = load_shot(before_dir), load_shot(after_dir)
        if after.num_frames != before.num_frames:
            raise ValueError(f"{after_dir}: {after.num_frames} frames, the before render has {before.num_frames}")
        edits = Edits.from_dict(doc["edits"], where=f"{doc.get('source', after_dir / 'edits.json')}: edits")
        target = doc.get("target")
        ids = [int(target["id"])] if target else None
        masks = []
        for t in range(before.num_frames):
            obj = np.isin(before.channel("ids", t)[..., 0], ids) if ids else np.ones(before.size, bool)
            masks.append(regions(obj) if ids else {"inside": obj, "band": ~obj, "outside": ~obj, "whole": obj})
        truth = [tonemap(after.channel("rgb", t)) for t in range(after.num_frames)]
        edges = [rings(~m["outside"]) for m in masks] if ids else None  # around the edit's reach: the object grown by BAND
        mid = before.num_frames // 2
        if keep is not None:
            keep[(kind, "cycles")] = truth[mid]
        row: dict[str, Any] = {"kind": kind, "seed": int(json.loads((folder / "before" / "shot.json").read_text())["extra"]["room_seed"]),
                               "target": target, "look": doc["look"], "cycles_seconds_per_frame": doc["cycles"]["seconds_per_frame"],
                               "cycles_passes_seconds_per_frame": doc["cycles"].get("passes_seconds_per_frame"), "methods": {}}
        if doc.get("reversed"):
            row["reversed"] = doc["reversed"]
        if edges is not None:
            row["seam_truth"] = seam(truth, edges)
        for method in methods:
            via = "bench"
            if method == "nothing":
                t0 = time.perf_counter()
                frames = [before.channel("rgb", t) for t in range(before.num_frames)]
                spf = 0.0
            elif method == "rebuild":
                t0 = time.perf_counter()
                frames = [rebuild(before, doc["look"], t, masks[t]["inside"]) for t in range(before.num_frames)]
                passes = kind in ("albedo", "light", "metal_off", "metal_on", MASKED)
                spf = (time.perf_counter() - t0) / before.num_frames if passes else 0.0
                via = "bench" if passes else "no pass holds it: the frames as they were"
            elif method in NEEDS_MODEL and (model is None or (method != "off" and model.residual_net is None)):
                row["methods"][method] = {"skipped": "needs the model's tier-1 net"}
                continue
            elif method in RENDER_OPTIONS and (kind != MASKED or not base_field):
                row["methods"][method] = {"skipped": "a generated frame's way over the base: only the masked kind generates"
                                          if base_field else "needs RenderSettings.base"}
                continue
            elif method == "off" or (base_field and method not in LIBRARY):
                frames, spf = renderer_frames(renderer, before, edits, method)
                via = f"Renderer ({renderer.last_tier.tier if renderer.last_tier else '?'})"
            else:
                frames, spf = library_frames(model, before, edits, method)
                via = "base.stage.edited_frame" + (f" {LIBRARY[method]}" if method in LIBRARY else "")
            if keep is not None:
                keep[(kind, method)] = tonemap(np.asarray(frames[mid], np.float32))
            sc = Scores()
            identical = True
            for t, f in enumerate(frames):
                sc.add(tonemap(np.asarray(f, np.float32)), truth[t], masks[t])
                if method.startswith("base-") and ids:
                    far = ~grow(masks[t]["inside"], BAND)
                    identical &= bool(np.array_equal(np.asarray(f, np.float32)[far], before.channel("rgb", t)[far]))
            res = {**sc.psnr(), "seconds_per_frame": spf, "via": via}
            if edges is not None:
                res["seam"] = seam([tonemap(np.asarray(f, np.float32)) for f in frames], edges)
            if method.startswith("base-") and ids:
                res["outside_bit_identical"] = identical
            cyc = doc["cycles"]["seconds_per_frame"]
            res["cycles_over_method"] = (cyc / spf) if spf > 0 and cyc else None
            row["methods"][method] = res
            jump = "" if edges is None else f" seam jump {_f(res['seam']['jump'])} (truth {_f(row['seam_truth']['jump'])})"
            log(f"room {row['seed']} {kind:9s} {method:13s} inside {_f(res['inside'])} band {_f(res['band'])} outside "
                f"{_f(res['outside'])} whole {_f(res['whole'])}{jump}  {spf:.3f} s/frame ({via})")
        rows.append(row)
    return rows


def _f(v: float | None) -> str:
    return "  -  " if v is None else f"{v:5.2f}"


# ---------------------------------------------------------------------------------------------- summary
def summarise(rows: list[dict], methods: tuple[str, ...]) -> dict:
    """Per kind: the mean over rooms of each method's region PSNRs, seam jump and seconds per frame, and Cycles' seconds."""
    out: dict[str, Any] = {}
    for kind in KINDS:
        mine = [r for r in rows if r["kind"] == kind]
        if not mine:
            continue
        cyc = float(np.mean([r["cycles_seconds_per_frame"] for r in mine]))
        entry: dict[str, Any] = {"rooms": len(mine), "cycles_seconds_per_frame": cyc,
                                 "cycles_passes_seconds_per_frame": _mean([r.get("cycles_passes_seconds_per_frame") for r in mine]),
                                 "targets": [r["target"] for r in mine], "methods": {}}
        if any("seam_truth" in r for r in mine):
            entry["seam_jump_truth"] = _mean([r["seam_truth"]["jump"] for r in mine if "seam_truth" in r])
        for m in methods:
            done = [r["methods"][m] for r in mine if m in r["methods"] and "skipped" not in r["methods"][m]]
            if not done:
                continue
            e = {reg: _mean([d[reg] for d in done]) for reg in REGIONS}
            e["seconds_per_frame"] = float(np.mean([d["seconds_per_frame"] for d in done]))
            e["cycles_over_method"] = cyc / e["seconds_per_frame"] if e["seconds_per_frame"] > 0 else None
            e["via"] = sorted({d["via"] for d in done})
            if any("seam" in d for d in done):
                e["seam_jump"] = _mean([d["seam"]["jump"] for d in done if "seam" in d])
            if any("outside_bit_identical" in d for d in done):
                e["outside_bit_identical"] = all(d.get("outside_bit_identical", True) for d in done)
            entry["methods"][m] = e
        out[kind] = entry
    return out


def _mean(vals: list[float | None]) -> float | None:
    v = [x for x in vals if x is not None]
    return float(np.mean(v)) if v else None


def markdown(doc: dict) -> str:
    """The tables of a result (one per edit kind), made from its JSON."""
    lines = [f"# Edits over path-traced frames ({doc['split']} rooms {', '.join(map(str, doc['data']['seeds']))})", "",
             f"`{doc['command']}` on {doc['machine'].get('cpu', '?')}; {doc['data']['frames']} frames at "
             f"{doc['data']['size'][0]}x{doc['data']['size'][1]}, Cycles {doc['data']['samples']} spp + OIDN before and after. "
             "PSNR (dB) against Cycles' re-render of the edit on display images; inside the edited object, a "
             f"{BAND}-px band around it, outside both, whole frame (the light edit's inside is the whole frame). "
             f"RenderSettings.base present: {doc['base_field']}.", ""]
    for kind, e in doc["kinds"].items():
        targets = ", ".join(sorted({t["caption"] or t["category"] for t in e["targets"] if t})) or "every light"
        lines += [f"## {kind} ({targets}; {e['rooms']} room(s), Cycles re-render {e['cycles_seconds_per_frame']:.2f} s/frame)", "",
                  "| method | inside | band | outside | whole | s/frame | x faster than Cycles |", "|---|---|---|---|---|---|---|"]
        for m, r in e["methods"].items():
            speed = "-" if r["cycles_over_method"] is None else f"{r['cycles_over_method']:.0f}"
            cells = [("-" if r[reg] is None else f"{r[reg]:.2f}") for reg in REGIONS]
            lines.append(f"| {m} | {' | '.join(cells)} | {r['seconds_per_frame']:.3f} | {speed} |")
        lines.append("")
        if e.get("seam_jump_truth") is not None:
            jumps = ", ".join(f"{m} {r['seam_jump']:.2f}" for m, r in e["methods"].items() if r.get("seam_jump") is not None)
            lines += [f"Seam at the edge of the edit's reach (mean |gradient| on the ring across it over that just inside and "
                      f"outside; Cycles' re-render {e['seam_jump_truth']:.2f}): {jumps}", ""]
    if doc.get("picture"):
        pic = doc["picture"]
        lines += [f"![room {pic['seed']}, {pic['kind']}: as rendered, by x2video ({pic['method']}), by Cycles]({pic['file']})", ""]
    lines += [f"- {n}" for n in doc["notes"]]
    return "\n".join(lines) + "\n"


NOTES = ["rebuild: roughness and metallic edits have no pass to rebuild from, so it is the frames as they were; the light "
         "edit's rebuild grades every pass by the light's change, exact when every light changes together as here",
         "x2video frames are timed with the model loaded and warmed on two frames, the conditioning cache emptied; "
         "Cycles' seconds are its re-render of the picture alone (no passes or AOVs; the same samples + OIDN; "
         "frames 1 to 3, after the first has built the scene): what a person waits for to see the change. The render with every pass "
         "that made the truth took cycles_passes_seconds_per_frame",
         "timings are wall seconds on a machine shared with other jobs (load_average_before_after): ratios are rough",
         "PSNR of a region is that of the squared error pooled over a room's frames, then averaged over rooms",
         "metal_off in a room with no metal (the rooms' 'skipped'): the metal_on pair reversed (`edit_pair`): the Cycles render "
         "with the object made metal is the shot, the before render the truth, the edit sets metallic back",
         "masked: the albedo pair, the object's albedo, metallic and roughness masked out and a local prompt naming the colour "
         "(`bench.edits_masked`); base-auto adds the diffusion tier's frame minus tier 1's frame of the unedited channels "
         "over the base inside the reach, base-auto-replace replaces the base with that frame"]


def picture(keep: dict, row: dict, method: str, path: Path) -> dict:
    """The README's picture: one frame as rendered, after the edit by `method`, and Cycles' re-render of the edit, each
    with its seconds per frame and PSNR against Cycles (`bench.side_by_side.compose`)."""
    from bench.side_by_side import Panel, compose, scored

    kind, gt = row["kind"], keep[(row["kind"], "cycles")]
    m = row["methods"][method]
    what = (row["target"] or {}).get("caption") or "every light"
    panels = [scored(Panel("before", "as rendered", keep[(kind, "nothing")], None), gt),
              scored(Panel(method, f"x2video ({method})", keep[(kind, method)], m["seconds_per_frame"]), gt),
              Panel("cycles", "Cycles' re-render", gt, row["cycles_seconds_per_frame"], caption=f"{row['cycles_seconds_per_frame']:.2f} s/frame")]
    return compose(panels, path, footer=f"room {row['seed']}, edit: {kind} of {what}; PSNR against Cycles' re-render, display images")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default=None, help="bench.edits_data's folder (default: its cache folder for --size)")
    ap.add_argument("--size", default="320x224", help="WxH of the default root")
    ap.add_argument("--seeds", default=None, help=f"room seeds (default the test rooms {TEST_SEEDS})")
    ap.add_argument("--validation", action="store_true", help=f"score the validation rooms {EDITS_VALIDATION_SEEDS} (edits_validation.json)")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--weights", default=None, help="checkpoint folder (default: the shipped weights)")
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    ap.add_argument("--out", type=Path, default=None, help="result JSON (default bench/results/edits/edits[_validation].json)")
    ap.add_argument("--picture", default="albedo:base-auto", help="KIND:METHOD of the picture beside the JSON (the first room's "
                    "middle frame as rendered, after the edit, and by Cycles); '' for none")
    args = ap.parse_args(argv)
    w, h = parse_size(args.size)
    root = Path(args.root) if args.root else default_root(w, h)
    seeds = [int(s) for s in (args.seeds or (EDITS_VALIDATION_SEEDS if args.validation else TEST_SEEDS)).split(",") if s]
    methods = tuple(m for m in args.methods.split(",") if m)
    bad = [m for m in methods if m not in METHODS]
    if bad:
        ap.error(f"--methods: unknown {bad} (one of {', '.join(METHODS)})")
    kinds = tuple(k for k in args.kinds.split(",") if k)
    missing = [s for s in seeds if not (root / f"room_{s}" / "room.json").is_file()]
    if missing:
        raise SystemExit(f"{root}: no rendered room {missing} (render them: python -m bench.edits_data --seeds "
                         f"{','.join(map(str, missing))} --size {w}x{h})")
    import torch

    torch.set_num_threads(args.threads)
    from x2video.eval.machine import machine_info
    from x2video.io.atomic import write_json_atomic
    from x2video.io.paths import portable_path
    from x2video.weights import load_model, shipped_weights

    model = load_model(args.weights, device="cpu") if any(m in NEEDS_MODEL for m in methods) else None
    load = [round(v, 2) for v in os.getloadavg()]
    keep: dict = {}
    rows = [r for i, s in enumerate(seeds) for r in score_room(root / f"room_{s}", kinds, methods, model, keep=keep if i == 0 else None)]
    room0 = json.loads((root / f"room_{seeds[0]}" / "room.json").read_text())
    split = "validation" if args.validation else ("test" if seeds == [int(s) for s in TEST_SEEDS.split(",")] else "chosen")
    doc = {"format": "x2video-edits", "command": command("edits", argv), "machine": machine_info("cpu"), "split": split,
           "data": {"root": portable_path(root), "seeds": seeds, "frames": room0["frames"], "size": room0["size"], "samples": room0["samples"]},
           "weights": None if model is None else portable_path(args.weights or shipped_weights()),
           "base_field": has_base_field(), "threads": args.threads, "band_px": BAND,
           "kinds": summarise(rows, methods), "rooms": rows, "notes": NOTES,
           "skipped": {f"room_{s}": {k: v["skipped"] for k, v in json.loads((root / f"room_{s}" / "room.json").read_text())["kinds"].items()
                                      if "skipped" in v} for s in seeds},
           "load_average_before_after": [load, [round(v, 2) for v in os.getloadavg()]]}
    out = args.out or results_path("edits", "edits_validation" if args.validation else "edits")
    out.parent.mkdir(parents=True, exist_ok=True)
    pk, _, pm = args.picture.partition(":")
    first = next((r for r in rows if r["seed"] == seeds[0] and r["kind"] == pk and pm in r["methods"] and "skipped" not in r["methods"][pm]), None)
    if first is not None and (pk, "nothing") in keep:
        doc["picture"] = {"file": out.with_suffix(".png").name, "kind": pk, "method": pm, "seed": first["seed"],
                          **picture(keep, first, pm, out.with_suffix(".png"))}
    doc = clean_json(doc, 4)
    write_json_atomic(out, doc)
    out.with_suffix(".md").write_text(markdown(doc))
    print(f"wrote {out} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
