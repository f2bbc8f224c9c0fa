"""The masked kind of `bench.edits` (issue 52): an object's materials masked out (A|M|R) with a local prompt describing
its new look, which the diffusion tier generates; and the seam statistic at the edge of an edit's reach.

It needs no Cycles render of its own: it reuses a room's albedo pair (``after_albedo/`` is the truth), the x2video edit
masking out the object's albedo, metallic and roughness (`x2video.edits.ops.MaskOut`) and binding a local prompt to the
same mask ("a yellow cabinet": the recolour's colour name and the object's category), as a person who cannot say the
colour numerically would.

The seam statistic (`Seam`): mean |gradient| of a display image's luminance on the ring straddling the reach's edge (one
pixel either side), against the mean of the same just inside (2 to 5 px in) and just outside (2 to 5 px out); a
blend that leaves a step where the generated frame meets the base raises the ring's gradient over its neighbours'.
Its ``jump`` (ring / mean of inside and outside) is read beside the truth's own on the same pixels.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bench.edits_data import COLOURS

KIND = "masked"
#: names of `bench.edits_data.COLOURS` (linear RGB) as a person would say them of the sRGB colour seen
COLOUR_NAMES = dict(zip(COLOURS, ("red", "green", "blue", "yellow")))
#: the channels the masked kind masks out (the paper's A|M|R)
AMR = ("albedo", "metallic", "roughness")
#: pixels of each ring of the seam statistic: the edge ring is `EDGE` px either side of the reach's edge; the rings
#: beside it lie `EDGE` + 1 to `NEAR` px in and out
EDGE, NEAR = 1, 5


def colour_name(color: Any) -> str:
    """The name of one of `COLOURS` (ValueError naming it where it is none of them)."""
    key = tuple(float(c) for c in color)
    if key not in COLOUR_NAMES:
        raise ValueError(f"look colour {list(key)}: not one of bench.edits_data.COLOURS {list(COLOUR_NAMES)}: no name for the local prompt")
    return COLOUR_NAMES[key]


def local_prompt(color: Any, category: str) -> str:
    """The local prompt of the masked kind: 'a <colour name> <category>' ('a yellow cabinet')."""
    return f"a {colour_name(color)} {category}"


def masked_edits(object_id: int, prompt: str) -> dict:
    """The masked edit in x2video's terms: an `x2video.Edits` dict whose mask selects the object by id, with a `MaskOut`
    of `AMR` and the local prompt `prompt` bound to that mask."""
    from x2video.edits.model import Edits
    from x2video.edits.ops import MaskOut

    edits = Edits()
    name = edits.add_mask(f"object {object_id}")
    edits.masks[name].add_id(int(object_id))
    edits.ops.append(MaskOut(mask=name, channels=list(AMR)))
    edits.set_local_prompt(name, prompt)
    edits.validate()
    return edits.to_dict()


def masked_pair(folder: Path) -> tuple[Path, Path, dict] | None:
    """(the shot, Cycles' render of the change, the edit's record) of the masked kind in a room: the albedo pair with the
    object's A|M|R masked out and a local prompt naming the colour Cycles rendered it; None where the room has no albedo pair."""
    src = folder / "after_albedo" / "edits.json"
    if not src.is_file():
        return None
    doc = json.loads(src.read_text())
    target, color = doc["target"], doc["look"]["color"]
    prompt = local_prompt(color, target.get("category") or "object")
    look = {"kind": KIND, "id": int(target["id"]), "color": list(color), "prompt": prompt, "channels": list(AMR)}
    rec = {"kind": KIND, "target": target, "look": look, "edits": masked_edits(int(target["id"]), prompt),
           "cycles": doc["cycles"], "source": str(src),
           "reused": "the albedo pair: after_albedo is the truth; the edit masks out A|M|R and says the colour in a local prompt"}
    return folder / "before", folder / "after_albedo", rec


def rings(reach: np.ndarray) -> dict[str, np.ndarray]:
    """(H, W) bool rings around the edge of `reach` (H, W) bool: 'edge' (within `EDGE` px of it, either side), 'inside'
    and 'outside' (`EDGE` + 1 to `NEAR` px from it); all empty where the reach is empty or the whole frame."""
    r = reach.astype(np.uint8)
    if r.all() or not r.any():
        empty = np.zeros(reach.shape, bool)
        return {"edge": empty, "inside": empty, "outside": empty}
    d_in = cv2.distanceTransform(r, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)  # reach pixels: distance to the nearest outside; 1 at its edge
    d_out = cv2.distanceTransform(1 - r, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)  # outside pixels: distance to the reach
    edge = (reach & (d_in <= EDGE)) | (~reach & (d_out <= EDGE))
    return {"edge": edge, "inside": reach & (d_in > EDGE) & (d_in <= NEAR), "outside": ~reach & (d_out > EDGE) & (d_out <= NEAR)}


def gradient(display: np.ndarray) -> np.ndarray:
    """(H, W) |gradient| (3x3 Sobel, divided by 8: per pixel) of a display image's (H, W, 3) mean over channels."""
    y = np.asarray(display, np.float32).mean(-1)
    gx = cv2.Sobel(y, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REFLECT)
    gy = cv2.Sobel(y, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REFLECT)
    return np.sqrt(gx * gx + gy * gy) / 8


class Seam:
    """The seam statistic of a method over a room's frames (the module docstring): |gradient| summed per ring, pooled."""

    def __init__(self) -> None:
        self.sum = dict.fromkeys(("edge", "inside", "outside"), 0.0)
        self.n = dict.fromkeys(("edge", "inside", "outside"), 0)

    def add(self, display: np.ndarray, ring: dict[str, np.ndarray]) -> None:
        g = gradient(display)
        for k, m in ring.items():
            self.sum[k] += float(g[m].sum())
            self.n[k] += int(m.sum())

    def result(self) -> dict[str, float | None]:
        """{'edge', 'inside', 'outside': mean |gradient|, 'jump': edge / mean(inside, outside)}; None where a ring is empty."""
        mean = {k: (self.sum[k] / self.n[k] if self.n[k] else None) for k in self.sum}
        e, i, o = mean["edge"], mean["inside"], mean["outside"]
        jump = e / ((i + o) / 2) if e is not None and i is not None and o is not None and i + o > 0 else None
        return {**mean, "jump": jump}


def seam(displays: list[np.ndarray], edges: list[dict[str, np.ndarray]]) -> dict[str, float | None]:
    """`Seam.result` of a room's display frames, each with its `rings`, pooled over them."""
    sm = Seam()
    for d, ring in zip(displays, edges):
        sm.add(d, ring)
    return sm.result()
