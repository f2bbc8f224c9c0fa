"""A data set folder: shot folders, each finished when its shot.json is there (written last), under `train/`, `test/` ..."""
from __future__ import annotations

from pathlib import Path


def shot_dirs(root: str | Path, split: str | None = None) -> list[Path]:
    """The finished shot folders (those holding a shot.json) of `root/split` (`split` None: of `root` itself), sorted by
    name. FileNotFoundError when `root` is missing; no folder `split` gives [] (a data set without that split); ValueError
    when `root` is itself one shot folder."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"data set folder not found: {root}")
    base = root if split is None else root / split
    if not base.is_dir():
        if (root / "shot.json").is_file():
            raise ValueError(f"{root} is one shot folder; --data wants a data set folder with train/ and test/ rooms")
        return []
    return sorted(p for p in base.iterdir() if p.is_dir() and (p / "shot.json").is_file())
