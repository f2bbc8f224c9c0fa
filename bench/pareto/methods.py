"""The rows bench.pareto measures: each a Method (a tier, a sampler's steps and scheme, or Cycles' samples), parsed
from its key ('formula', 'residual', 'ddim-20', 'lcm-2-seq', 'cycles-64'), with the render settings that make it."""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import Any

from bench.ptscore import render_timed
from x2video.tiers import registry as tiers
from x2video.tiers.base import TIERS, Tier

METHODS = ("formula", "residual", "ddim-1", "ddim-2", "ddim-4", "ddim-8", "ddim-20", "lcm-1", "lcm-2", "lcm-4",
           "ddim-4-seq", "ddim-20-seq", "lcm-2-seq", "cycles-4", "cycles-16", "cycles-64")

FAMILY_NAMES = {"formula": "formula (tier 0)", "residual": "tier 1 (residual net)", "ddim-recursive": "DDIM, recursive",
                "ddim-sequential": "DDIM, sequential", "lcm-recursive": "LCM, recursive", "lcm-sequential": "LCM, sequential",
                "cycles": "Cycles + OIDN"}


@dataclass(frozen=True)
class Method:
    key: str  # as given: "ddim-20-seq"
    kind: str  # a tier's name (formula | residual | diffusion) or cycles
    sampler: str = ""
    steps: int = 0
    scheme: str = "recursive"
    samples: int = 0

    @property
    def tier(self) -> Tier | None:
        """The tier whose renders this method measures (None: Cycles)."""
        return None if self.kind == "cycles" else tiers.get(self.kind)

    @property
    def windowed(self) -> bool:
        """The sampler's windows (the diffusion tier): its sampler, steps and scheme name the method."""
        return tiers.windowed(self.kind)

    @property
    def needs_model(self) -> bool:
        tier = self.tier
        return tier is not None and tier.needs_model

    @property
    def label(self) -> str:
        if self.kind == "cycles":
            return f"Cycles {self.samples} spp + OIDN"
        if self.windowed:
            return f"{self.sampler.upper()}-{self.steps}" + (" sequential" if self.scheme == "sequential" else "")
        return FAMILY_NAMES.get(self.kind, self.kind)

    @property
    def family(self) -> str:
        """Points joined by a line in the chart: the DDIM steps, the LCM steps, the Cycles samples."""
        if self.windowed:
            return f"{self.sampler}-{self.scheme}"
        return self.kind


def parse_method(text: str) -> Method:
    """'formula', 'residual', 'ddim-20', 'lcm-2-seq', 'cycles-64' -> Method; a clear error otherwise."""
    t = text.strip().lower()
    if t in TIERS and not tiers.windowed(t):  # a per-frame tier is named by itself
        return Method(t, t)
    m = re.fullmatch(r"(ddim|lcm)-(\d+)(-seq)?", t)
    if m:
        return Method(t, "diffusion", m.group(1), int(m.group(2)), "sequential" if m.group(3) else "recursive")
    m = re.fullmatch(r"cycles-(\d+)", t)
    if m:
        return Method(t, "cycles", samples=int(m.group(1)))
    raise ValueError(f"--methods: unknown method {text!r} (formula, residual, ddim-S, lcm-S, ddim-S-seq, lcm-S-seq, cycles-S)")


def diffusion_settings(m: Method, frames: int):
    from x2video.render.settings import RenderSettings

    if m.windowed:
        return RenderSettings(quality=m.kind, sampler=m.sampler, steps=m.steps, scheme=m.scheme, frames=(0, frames), base="off")
    return RenderSettings(quality=m.kind, frames=(0, frames), base="off")


def same_plan(model: Any, shot: Any, m: Method, frames: int) -> bool:
    """Whether sequential sampling of `m` runs exactly the windows recursive sampling does (short shots)."""
    from x2video.render.renderer import Renderer

    r = Renderer(model)
    s = diffusion_settings(m, frames)
    key = lambda plan: [(w.frames, w.generate, w.refs) for w in plan]  # noqa: E731 - 'key' and 'seq' windows sample alike
    return key(r.plan(shot, s)) == key(r.plan(shot, dataclasses.replace(s, scheme="recursive")))


def warm_up(model: Any, shots: list, nframes: list[int], methods: list[Method]) -> None:
    """Untimed renders of the frames the rows render, one per network and scheme the methods use (1 step): first-call
    costs stay out of the rows, among them the diffusion engine's graphs, which are exported and compiled per window
    size and window kind (`x2video.model.engine`: a 2-frame warm-up left a 3-, 4- or 5-frame window's to the first row)."""
    from x2video.render.renderer import Renderer

    kinds = {(m.kind, m.sampler, m.scheme if m.windowed else "") for m in methods if m.needs_model}
    firsts: dict[int, Any] = {}
    for s, n in zip(shots, nframes):
        firsts.setdefault(n, s)  # one shot per frame count: the windows depend on nothing else
    for kind, sampler, scheme in sorted(kinds):
        m = Method("warm", kind, sampler, 1, scheme) if tiers.windowed(kind) else Method("warm", kind)
        for n, shot in firsts.items():
            render_timed(Renderer(model), shot, diffusion_settings(m, n))
