"""The four tables `x2video eval` fills, shaped like the paper's (Tab. quantitative, multi-modal, abl_sampling, acceleration).

(a) image model run per frame vs the video model, full channels (paper Tab. quantitative: XRGB vs Ours);
(b) full channels vs Mask A|M|R vs Drop irradiance, each plain, + Text and + Ref. (Tab. multi-modal);
(c) Sequential vs Recursive sampling on long (65-frame) shots (Tab. abl_sampling);
(d) DDIM-20 vs LCM-2, with and without the reference frame (Tab. acceleration).
A row is pure data (`RowSpec`); rows with the same render key are rendered once and shared.
"""
from __future__ import annotations

from dataclasses import dataclass

from x2video.eval.conditions import KINDS, Condition, parse_condition
from x2video.eval.config import EvalConfig

TITLES = {
    "a": "Image model per frame vs video model (full channels)",
    "b": "Multi-modal controls: Mask A|M|R and Drop irradiance, + Text, + Ref.",
    "c": "Recursive vs sequential sampling on long shots",
    "d": "Acceleration: DDIM vs LCM, with and without the reference frame",
}

#: the paper's figures for context (its data, its 640x448 SD-2.1-sized model, its GPU): label -> metrics
PAPER = {
    "a": {
        "Image model (per frame)": {"fid": 13.3682, "fvd": 672.5979, "psnr": 14.6443, "ssim": 0.7641, "lpips": 0.1350, "tc": 3.5050, "seconds_per_frame": 0.89},
        "Video model": {"fid": 8.0562, "fvd": 69.3828, "psnr": 22.6641, "ssim": 0.8931, "lpips": 0.0618, "tc": 1.0115, "seconds_per_frame": 1.08},
    },
    "b": {
        "Full channels": {"fid": 8.0562, "fvd": 69.3828, "psnr": 22.6641},
        "Mask A|M|R": {"fid": 10.8333, "fvd": 89.1932, "psnr": 20.7702},
        "Mask A|M|R + Text": {"fid": 9.9492, "fvd": 80.6469, "psnr": 21.6770},
        "Mask A|M|R + Ref.": {"fid": 5.9785, "fvd": 49.4391, "psnr": 25.3979},
        "Drop irradiance": {"fid": 12.0103, "fvd": 111.7795, "psnr": 19.0853},
        "Drop irradiance + Text": {"fid": 11.1065, "fvd": 101.4572, "psnr": 20.0103},
        "Drop irradiance + Ref.": {"fid": 6.9414, "fvd": 58.6867, "psnr": 23.6756},
        "Full channels + Ref.": {"fid": 5.2770, "fvd": 42.4124, "psnr": 26.2617, "tc": 1.0165},
    },
    "c": {
        "Sequential": {"fid": 9.1433, "fvd": 79.1601, "psnr": 21.5126, "tc": 1.0324},
        "Recursive": {"fid": 8.0562, "fvd": 69.3828, "psnr": 22.6641, "tc": 1.0115},
    },
    "d": {
        "DDIM-20": {"fid": 8.0562, "fvd": 69.3828, "psnr": 22.6641, "tc": 1.0115, "seconds_per_frame": 1.08},
        "DDIM-20 + Ref.": {"fid": 5.2770, "fvd": 42.4124, "psnr": 26.2617, "tc": 1.0165, "seconds_per_frame": 1.20},
        "LCM-2 + Ref.": {"fid": 5.4832, "fvd": 45.6137, "psnr": 25.1470, "tc": 1.0297, "seconds_per_frame": 0.24},
    },
}
PAPER_NOTE = (
    "paper figures: InteriorVideo test set (237 rooms), SD-2.1-sized model at 640x448, 50k steps on 8 GPUs, "
    "timed on one RTX 5880 Ada; our rows: procedural rooms, our model and machine. Context only, not comparable numbers."
)


@dataclass(frozen=True)
class RowSpec:
    """One row: which model renders which condition with which sampler, on which data set."""

    table: str
    label: str
    model: str  # "video" | "image" | "lcm"
    condition: Condition
    sampler: str = "ddim"
    steps: int = 20
    scheme: str = "recursive"
    data: str = "main"  # "main" (--data, --frames) | "long" (--long-data, --long-frames)

    def render_key(self) -> tuple:
        """Rows with equal keys produce identical renders (same weights, inputs, settings and seed)."""
        return (self.model, self.condition, self.sampler, self.steps, self.scheme, self.data)

    def baseline_key(self) -> tuple:
        """Rows with equal keys share the classical baseline (it ignores text, reference and sampler)."""
        return (self.condition.kind, self.condition.masks, self.data)

    def settings(self) -> dict:
        return {"model": self.model, "sampler": self.sampler, "steps": self.steps, "scheme": self.scheme, "data": self.data}


def table_rows(config: EvalConfig) -> dict[str, list[RowSpec]]:
    """The rows of each requested table, in display order."""
    s, m = config.steps, config.masks
    full = Condition("full", masks=m)
    out: dict[str, list[RowSpec]] = {}
    for t in config.tables:
        if t == "a":
            out[t] = [
                RowSpec("a", "Image model (per frame)", "image", full, "ddim", s, "sequential"),
                RowSpec("a", "Video model", "video", full, "ddim", s, "recursive"),
            ]
        elif t == "b":
            rows = []
            for kind in KINDS:
                for text, ref in ((False, False), (True, False), (False, True)):
                    c = Condition(kind, text, ref, m)
                    rows.append(RowSpec("b", c.label, "video", c, "ddim", s))
            out[t] = rows
        elif t == "c":
            out[t] = []
            for token in config.long_conditions:
                c = parse_condition(token, m)
                suffix = "" if c == full else f", {c.label}"
                out[t] += [
                    RowSpec("c", f"Sequential{suffix}", "video", c, "ddim", s, "sequential", "long"),
                    RowSpec("c", f"Recursive{suffix}", "video", c, "ddim", s, "recursive", "long"),
                ]
        elif t == "d":
            ref = Condition("full", reference=True, masks=m)
            k = config.lcm_steps
            out[t] = [
                RowSpec("d", f"DDIM-{s}", "video", full, "ddim", s),
                RowSpec("d", f"DDIM-{s} + Ref.", "video", ref, "ddim", s),
                RowSpec("d", f"LCM-{k}", "lcm", full, "lcm", k),
                RowSpec("d", f"LCM-{k} + Ref.", "lcm", ref, "lcm", k),
            ]
    return out
