"""The demo shot a new user sees first: one procedural room, generated once and cached.

    python -m x2video.procedural.demo [CACHE]      # prints DEMO=<shot folder>
"""
from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

log = logging.getLogger(__name__)

#: the demo room: scene seed, frames and size (deterministic)
DEMO = {"seed": 7, "frames": 33, "width": 320, "height": 224}
#: where the demo shot is cached unless told otherwise (X2VIDEO_DEMO_DIR overrides it)
DEMO_CACHE = Path("~/.cache/x2video/demo").expanduser()


def demo_cache() -> Path:
    """X2VIDEO_DEMO_DIR if set (tests), else ~/.cache/x2video/demo."""
    env = os.environ.get("X2VIDEO_DEMO_DIR")
    return Path(env) if env else DEMO_CACHE


def write_demo(out: str | Path, renderer=None) -> Path:
    """Write the demo shot into the folder `out` (replacing it)."""
    from x2video.procedural.shotgen import write_procedural_shot

    write_procedural_shot(out, DEMO["seed"], DEMO["frames"], DEMO["width"], DEMO["height"], renderer=renderer, overwrite=True)
    return Path(out)


def ensure_demo(cache: str | Path | None = None) -> Path:
    """The demo shot's folder under `cache` (default `demo_cache()`), generated on first use."""
    cache = Path(cache) if cache is not None else demo_cache()
    folder = cache / f"seed{DEMO['seed']}-{DEMO['frames']}f-{DEMO['width']}x{DEMO['height']}"
    if not (folder / "shot.json").is_file():
        log.info("generating the demo shot in %s (once)", folder)
        folder.parent.mkdir(parents=True, exist_ok=True)
        write_demo(folder)
    return folder


if __name__ == "__main__":
    print("DEMO=" + str(ensure_demo(sys.argv[1] if len(sys.argv) > 1 else None)))
