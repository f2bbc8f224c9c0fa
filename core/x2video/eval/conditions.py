"""The control conditions of the paper's Tab. multi-modal as `Edits`: full channels, Mask A|M|R, Drop irradiance, + text, + reference.

- "full": all five channels, no prompt, no reference.
- "mask_amr": albedo, metallic and roughness of `masks` random objects zeroed (the paper masks
  three); objects are drawn, per shot and seed, among those covering >= 0.5 % of the frame on
  average, so a mask is never an invisible sliver.
- "drop_irradiance": the irradiance channel dropped.
- + text: the global prompt is the shot's caption (room style and light mood); for masked
  objects each mask carries its object's caption as local prompt (Masked Cross-Attention).
- + reference: the ground-truth first frame (`rgb/` frame 0) as the reference frame (the
  paper's "Ref-First"); frame 0 is then in the metrics like every other frame.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from x2video.edits import Edits, Mask, MaskOut, Reference
from x2video.shot import Shot

KINDS = ("full", "mask_amr", "drop_irradiance")
KIND_LABELS = {"full": "Full channels", "mask_amr": "Mask A|M|R", "drop_irradiance": "Drop irradiance"}
#: an object must cover this fraction of the frame (mean over sampled frames) to be masked
MIN_COVERAGE = 0.005


@dataclass(frozen=True)
class Condition:
    """What the model is given for a row."""

    kind: str = "full"
    """one of KINDS"""
    text: bool = False
    """global prompt = shot caption; local prompts = masked objects' captions"""
    reference: bool = False
    """the ground-truth first frame as reference"""
    masks: int = 3
    """objects masked out for kind "mask_amr" (paper: 3)"""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown condition {self.kind!r} (one of {', '.join(KINDS)})")

    @property
    def label(self) -> str:
        parts = [KIND_LABELS[self.kind]]
        if self.text:
            parts.append("Text")
        if self.reference:
            parts.append("Ref.")
        return " + ".join(parts)

    @property
    def token(self) -> str:
        """The condition as `parse_condition` reads it: kind[+text][+ref]."""
        return self.kind + ("+text" if self.text else "") + ("+ref" if self.reference else "")

    def to_dict(self) -> dict:
        d = {"kind": self.kind, "text": self.text, "reference": self.reference}
        if self.kind == "mask_amr":
            d["masks"] = self.masks
        return d


def parse_condition(token: str, masks: int = 3) -> Condition:
    """A `Condition` from "kind[+text][+ref]" (e.g. "mask_amr+ref"), as `x2video eval --long-conditions` takes it."""
    kind, *extras = [p.strip() for p in token.strip().split("+")]
    bad = [e for e in extras if e not in ("text", "ref")]
    if kind not in KINDS or bad or len(set(extras)) != len(extras):
        raise ValueError(f"condition {token!r}: expected KIND[+text][+ref] with KIND one of {', '.join(KINDS)}")
    return Condition(kind, "text" in extras, "ref" in extras, masks)


def visible_objects(shot: Shot, samples: int = 5) -> dict[int, float]:
    """Object id -> mean fraction of the frame it covers, over `samples` evenly spaced frames (id 0 excluded)."""
    if not shot.has("ids"):
        return {}
    n = shot.num_frames
    ts = sorted({round(i * (n - 1) / max(samples - 1, 1)) for i in range(samples)})
    cover: dict[int, float] = {}
    for t in ts:
        ids = shot.channel("ids", t)[..., 0]
        vals, counts = np.unique(ids, return_counts=True)
        for v, c in zip(vals.tolist(), counts.tolist()):
            if v != 0:
                cover[v] = cover.get(v, 0.0) + c / ids.size / len(ts)
    return cover


def pick_objects(shot: Shot, name: str, count: int, seed: int) -> list[int]:
    """`count` object ids drawn without replacement (deterministic in seed and shot name) among visible objects."""
    cover = visible_objects(shot)
    pool = sorted(i for i, c in cover.items() if c >= MIN_COVERAGE)
    if not pool:
        raise ValueError(f"shot {name!r}: no object covers {MIN_COVERAGE:.1%} of the frame; cannot build 'Mask A|M|R'")
    rng = np.random.default_rng([seed, zlib.crc32(name.encode())])
    return sorted(int(i) for i in rng.choice(pool, size=min(count, len(pool)), replace=False))


def build_edits(shot: Shot, name: str, cond: Condition, seed: int) -> tuple[Edits | None, dict]:
    """(Edits, description) for `cond` on `shot`; Edits None for the plain full-channel row."""
    desc: dict = {}
    if cond.kind == "full" and not cond.text and not cond.reference:
        return None, desc
    edits = Edits()
    if cond.kind == "drop_irradiance":
        edits.dropped = {"irradiance"}
    elif cond.kind == "mask_amr":
        objects = pick_objects(shot, name, cond.masks, seed)
        captions = shot.info.object_captions
        desc["objects"] = {str(i): captions.get(i, "") for i in objects}
        for i in objects:
            mask = f"object {i}"
            edits.masks[mask] = Mask(ids=[i])
            edits.ops.append(MaskOut(mask=mask))
            if cond.text and captions.get(i, "").strip():
                edits.local_prompts[mask] = captions[i]
    if cond.text:
        edits.global_prompt = shot.info.caption
        desc["global_prompt"] = shot.info.caption
        if edits.local_prompts:
            desc["local_prompts"] = list(edits.local_prompts.values())
    if cond.reference:
        edits.reference = Reference(frame=0)
        desc["reference"] = "ground-truth rgb frame 0"
    edits.validate()
    return edits, desc
