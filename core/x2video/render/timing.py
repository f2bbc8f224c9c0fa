"""Where a render's wall time goes: `StageTimes`, filled by a `Renderer` whose `timing` is set (bench/render.py)."""
from __future__ import annotations

import contextlib
import time
from contextlib import contextmanager
from typing import Callable, Iterator

#: the stages of a render `StageTimes` splits wall time into (`x2video.render.renderer.Renderer.timing`)
STAGES = ("read", "base", "encode", "unet", "decode", "detail", "residual", "write")


class StageTimes:
    """Wall seconds and calls per stage of one render, for benchmarks: read (channels from the shot, edits
    applied), base (a shot's path-traced frame, or its fill between keyframes: `x2video.base.stage`), encode
    (conditioning latents), unet (every network call of the sampler), decode (VAE), detail (the shading detail
    residual models add back), residual (the tier-1 net), write (the `FramesReady`
    callback: a sink writing files, or the editor's queue). A `Renderer` fills one when its `timing` is set
    (off by default: then nothing is timed); `total` is the render's wall time and `other` what no stage
    holds (sampler arithmetic, noise, prompts, planning)."""

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self.clock = clock
        self.reset()

    def reset(self) -> None:
        self.seconds = dict.fromkeys(STAGES, 0.0)
        self.calls = dict.fromkeys(STAGES, 0)
        self.total = 0.0

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Add the block's wall time to stage `name` (also when it raises)."""
        start = self.clock()
        try:
            yield
        finally:
            self.seconds[name] += self.clock() - start
            self.calls[name] += 1

    def wrap(self, name: str, fn: Callable) -> Callable:
        """`fn` with each call timed as stage `name`."""

        def timed(*args, **kwargs):
            with self.stage(name):
                return fn(*args, **kwargs)

        return timed

    def as_dict(self, frames: int | None = None) -> dict:
        """{"seconds": {stage: s}, "calls", "total", "other"[, "seconds_per_frame": {stage: s/frame}]}, rounded to 0.1 ms."""
        other = max(0.0, self.total - sum(self.seconds.values()))
        out: dict = {"seconds": {k: round(v, 4) for k, v in self.seconds.items()}, "calls": dict(self.calls),
                     "total": round(self.total, 4), "other": round(other, 4)}
        if frames:
            out["seconds_per_frame"] = {k: round(v / frames, 4) for k, v in [*self.seconds.items(), ("other", other), ("total", self.total)]}
        return out


class NoTimes:
    """`StageTimes`' interface doing nothing: what a Renderer uses while its `timing` is unset."""

    def stage(self, name: str) -> contextlib.nullcontext:
        return contextlib.nullcontext()

    def wrap(self, name: str, fn: Callable) -> Callable:
        return fn
