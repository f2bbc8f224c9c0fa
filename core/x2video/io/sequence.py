"""Finding the numbered frames of an image sequence in a folder (`<prefix><number>.<ext>`, no gaps)."""
from __future__ import annotations

import re
from pathlib import Path

from x2video.io.image import IMAGE_EXTENSIONS

FRAME_RE = re.compile(r"^(?P<prefix>.*?)(?P<num>\d+)(?P<ext>\.[A-Za-z]+)$")


def is_image(path: Path) -> bool:
    return path.suffix.lower() in IMAGE_EXTENSIONS and not path.name.startswith(".")


def numbered_frames(folder: str | Path) -> dict[int, Path]:
    """Frame number -> file of the sequence in `folder`, gaps allowed (a keyframe shot's rgb/). Raises ValueError naming
    the folder/file for: no frames, a file that is not numbered, mixed prefixes or extensions, duplicate numbers."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: not a folder")
    files = sorted(p for p in folder.iterdir() if p.is_file() and is_image(p))
    if not files:
        raise ValueError(f"{folder}: empty: no image frames (expected <prefix><number>.exr/.png/.jpg/.tif files)")
    numbered: dict[int, Path] = {}
    kinds: dict[tuple[str, str], Path] = {}
    for p in files:
        m = FRAME_RE.match(p.name)
        if m is None:
            raise ValueError(f"{p}: file name has no frame number (expected <prefix><number>{p.suffix})")
        kinds.setdefault((m["prefix"], m["ext"].lower()), p)
        n = int(m["num"])
        if n in numbered:
            raise ValueError(f"{p}: frame number {n} appears twice (also {numbered[n].name})")
        numbered[n] = p
    if len(kinds) > 1:
        a, b = list(kinds.values())[:2]
        raise ValueError(f"{folder}: mixed sequences: {a.name} and {b.name} differ in prefix or extension")
    return numbered


def find_frames(folder: str | Path) -> list[Path]:
    """The frames of the sequence in `folder`, in order.

    Accepts any prefix and zero padding, as long as all frames share prefix and extension and the
    numbers are consecutive. Raises ValueError naming the folder/file for: no frames, a file that
    is not numbered, mixed prefixes or extensions, duplicate or missing numbers.
    """
    numbered = numbered_frames(folder)
    nums = sorted(numbered)
    for prev, cur in zip(nums, nums[1:]):
        if cur != prev + 1:
            raise ValueError(
                f"{folder}: gap in frame numbering: {numbered[prev].name} is followed by {numbered[cur].name}"
                f" (frames {prev + 1}..{cur - 1} missing)"
            )
    return [numbered[n] for n in nums]
