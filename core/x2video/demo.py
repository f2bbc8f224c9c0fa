"""The demo shot a new user sees first (`x2video render --demo`, the editor's first start): the path-traced room of
`x2video.cycles.demo` where Blender's Python module is installed and its render works, else the rasterized
procedural room of `x2video.procedural.demo`, saying why in one log line. Either is made once and cached.

    python -m x2video.demo [CACHE]      # "progress DONE TOTAL SECONDS" lines while it renders, then DEMO=<shot folder>

X2VIDEO_DEMO_RENDERER picks the demo: auto (default: Cycles, else the rasterized room), cycles (Cycles or an
error) or raster (the rasterized room; the test suite sets it, so tests that open the demo do not path-trace).
"""
from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

from x2video.cycles.demo import CYCLES_DEMO, CyclesDemo, CyclesDemoUnavailable, Progress, ensure_cycles_demo
from x2video.procedural.demo import demo_cache
from x2video.procedural.demo import ensure_demo as ensure_raster_demo

log = logging.getLogger(__name__)

RENDERERS = ("auto", "cycles", "raster")
#: what a user is told the first start costs (README "First commands"; measured in x2video-demo.json of the shot)
STATED_TIME = "about 2 minutes on a free 2-core CPU, once"


def demo_renderer() -> str:
    """$X2VIDEO_DEMO_RENDERER (auto, cycles or raster; default auto)."""
    r = (os.environ.get("X2VIDEO_DEMO_RENDERER") or "auto").strip().lower()
    if r not in RENDERERS:
        raise ValueError(f"X2VIDEO_DEMO_RENDERER={r!r}: expected one of {', '.join(RENDERERS)}")
    return r


def ensure_demo(cache: str | Path | None = None, renderer: str | None = None, *, spec: CyclesDemo = CYCLES_DEMO,
                progress: Progress | None = None) -> Path:
    """The demo shot's folder under `cache` (default `demo_cache()`), made on first use: path-traced (`spec`; `progress`
    hears of each frame) unless `renderer` (default `demo_renderer()`) is 'raster' or Cycles is unavailable, when
    it is the rasterized room and a warning says why ('cycles': CyclesDemoUnavailable instead)."""
    cache = Path(cache) if cache is not None else demo_cache()
    renderer = renderer or demo_renderer()
    if renderer not in RENDERERS:
        raise ValueError(f"demo renderer {renderer!r}: expected one of {', '.join(RENDERERS)}")
    if renderer != "raster":
        try:
            folder = ensure_cycles_demo(cache, spec, progress)
            log.debug("the demo shot is the path-traced room in %s", folder)
            return folder
        except CyclesDemoUnavailable as e:
            if renderer == "cycles":
                raise
            log.warning("demo: the rasterized room, not the path-traced one: %s", e)
    return ensure_raster_demo(cache)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")

    def progress(done: int, total: int, seconds: float) -> None:
        print(f"progress {done} {total} {seconds:.3f}", flush=True)

    print("DEMO=" + str(ensure_demo(argv[0] if argv else None, progress=progress)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
