"""Seconds per frame, the paper's speed metric: wall-clock time of rendering divided by frames produced."""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator


@dataclass
class FrameTimer:
    """Accumulates wall-clock seconds and frame counts over any number of timed blocks.

    >>> timer = FrameTimer()
    >>> with timer.measure(frames=16):
    ...     render_shot()
    >>> timer.seconds_per_frame
    """

    seconds: float = 0.0
    frames: int = 0
    clock: Callable[[], float] = time.perf_counter
    """monotonic clock; tests may inject a fake one"""

    @contextmanager
    def measure(self, frames: int) -> Iterator["FrameTimer"]:
        """Time the block and count `frames` toward the total (only if the block finishes)."""
        if frames < 0:
            raise ValueError(f"FrameTimer: frames must be >= 0, got {frames}")
        start = self.clock()
        yield self
        self.seconds += self.clock() - start
        self.frames += frames

    @property
    def seconds_per_frame(self) -> float:
        """Total seconds / total frames; raises when no frame was timed."""
        if self.frames == 0:
            raise ValueError("FrameTimer: no frames were timed, seconds per frame is undefined")
        return self.seconds / self.frames

    def as_dict(self) -> dict[str, float | int]:
        return {"seconds": self.seconds, "frames": self.frames, "seconds_per_frame": self.seconds_per_frame}
