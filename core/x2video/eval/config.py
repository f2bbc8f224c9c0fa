"""`EvalConfig`: what `x2video eval` measures (which tables, shots, frames, size, sampler steps); field docstrings are CLI help."""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

from x2video.render.settings import RenderSettings
from x2video.sampling.planner import check_max_levels

TABLES = ("a", "b", "c", "d")


@dataclass
class EvalConfig:
    """Settings of one evaluation run (paper Sec. Experimental Results, docs/ARCHITECTURE.md "Measuring it")."""

    tables: tuple[str, ...] = TABLES
    """which tables: a = image vs video model, b = controls, c = recursive vs sequential, d = DDIM vs LCM"""
    split: str = "test"
    """data set split of held-out rooms (never trained on)"""
    rooms: int | None = None
    """first K rooms of the split (None: all)"""
    frames: int | None = 17
    """first T frames of each shot for tables a, b, d (None: whole shots)"""
    long_frames: int = 65
    """frames of each long shot for table c (the paper's 65-frame shots)"""
    long_conditions: tuple[str, ...] = ("full",)
    """conditions table c compares the schemes under, each KIND[+text][+ref] with KIND one of "full", "mask_amr",
    "drop_irradiance" (e.g. "mask_amr+ref"); with a shading prior the full-channel render is anchored to the
    formula, the others make the model generate, and +ref gives it the ground-truth frame 0 to carry along"""
    size: tuple[int, int] | None = None
    """(W, H) to evaluate at; None: the model's training size when recorded, else the data's"""
    steps: int = 20
    """DDIM steps of tables a-c and the DDIM row of d (paper: DDIM-20)"""
    lcm_steps: int = 2
    """LCM steps of table d (paper: 2)"""
    seed: int = 0
    """seed of the initial noise and of the random object masks"""
    window: int = 5
    """frames per window N (the paper's N = 5)"""
    replace_refs: bool = RenderSettings.replace_refs
    """hold the windows' reference frames at their noised latents between steps (`RenderSettings.replace_refs`)"""
    seams: bool = RenderSettings.seams
    """recursive rows: the seam pass that re-generates keyframes with their neighbours (`RenderSettings.seams`)"""
    max_levels: int | None = RenderSettings.max_levels
    """recursive rows: at most this many levels (`RenderSettings.max_levels`; None: as many as the shot needs)"""
    ref_dc: float = RenderSettings.ref_dc
    """interpolation windows: pull the generated frames' latent mean toward the references' (`RenderSettings.ref_dc`)"""
    resample: int = RenderSettings.resample
    """DDIM rows, windows with references: RePaint's resampling, each step taken this many times (`RenderSettings.resample`)"""
    noise: Literal["window", "frame"] = RenderSettings.noise
    """how the initial noise is seeded, 'window' or 'frame' (`RenderSettings.noise`); every row alike"""
    noise_shared: float = RenderSettings.noise_shared
    """with noise 'frame': the fraction of the noise's variance all frames share (`RenderSettings.noise_shared`)"""
    image_window: int = 32
    """the image model renders frames independently; it runs this many per UNet call"""
    masks: int = 3
    """objects masked in "Mask A|M|R" (paper: 3)"""
    fid: bool = True
    """compute FID (Inception-v3 features of every frame; ~0.3 s per frame on a CPU)"""
    tc: bool = True
    """compute temporal consistency"""

    def __post_init__(self) -> None:
        bad = [t for t in self.tables if t not in TABLES]
        if bad or not self.tables:
            raise ValueError(f"tables: {','.join(self.tables)!r}; choose from {','.join(TABLES)}")
        if self.frames is not None and self.frames < 2:
            raise ValueError(f"frames must be at least 2 (temporal consistency needs pairs), got {self.frames}")
        if self.long_frames < 2:
            raise ValueError(f"long_frames must be at least 2, got {self.long_frames}")
        from x2video.eval.conditions import KINDS, parse_condition

        bad = []
        for token in self.long_conditions:
            try:
                parse_condition(token)
            except ValueError:
                bad.append(token)
        if bad or not self.long_conditions:
            raise ValueError(f"long_conditions: {','.join(self.long_conditions)!r}; choose from {','.join(KINDS)}, "
                             "each optionally followed by +text and/or +ref")
        if self.steps < 1 or self.lcm_steps < 1:
            raise ValueError(f"steps must be at least 1 (got DDIM {self.steps}, LCM {self.lcm_steps})")
        if self.masks < 1:
            raise ValueError(f"masks must be at least 1, got {self.masks}")
        if self.window < 2 or self.image_window < 1:
            raise ValueError(f"window must be at least 2 and image_window at least 1 (got {self.window}, {self.image_window})")
        check_max_levels(self.max_levels)  # before hours of rendering, not at the first recursive row

    def to_dict(self) -> dict:
        d = asdict(self)
        d["tables"] = list(self.tables)
        d["long_conditions"] = list(self.long_conditions)
        d["size"] = None if self.size is None else list(self.size)
        return d
