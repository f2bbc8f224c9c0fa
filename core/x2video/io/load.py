"""`load_shot(path)`: detect a shot's format (folder per channel, multi-layer EXR, XRGB set, video per channel) and load it lazily."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from x2video.channels import INTRINSIC
from x2video.shot import Shot


def detect_format(path: str | Path) -> str:
    """"folder" | "multilayer" | "xrgb" | "video" for what `path` holds; ValueError when none fits."""
    from x2video.io.folder import channel_folders, pass_files

    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: does not exist")
    if p.is_file():
        if p.suffix.lower() == ".exr":
            return "multilayer"
        from x2video.io.video import video_prefix

        if video_prefix(p) is not None:
            return "video"
        if p.name.lower().endswith(tuple(f"-{c}{e}" for c in (*INTRINSIC, "ref") for e in (".png", ".jpg", ".jpeg", ".exr"))):
            return "xrgb"
        raise ValueError(f"{p}: not a shot (give a shot folder, a multi-layer EXR, an XRGB '<name>-albedo.png' file,"
                         " or a per-channel video '<name>_Albedo.mp4')")
    if channel_folders(p) or pass_files(p):
        return "folder"
    from x2video.io.video import channel_videos

    if channel_videos(p):
        return "video"
    from x2video.io.xrgb import find_xrgb_sets

    if find_xrgb_sets(p, strict=False):
        return "xrgb"
    exrs = [q for q in p.iterdir() if q.suffix.lower() == ".exr" and not q.name.startswith(".")]
    if exrs:
        return "multilayer"
    if (p / "shot.json").is_file():
        return "folder"  # FolderShot names what is missing
    raise ValueError(
        f"{p}: no shot found (expected channel folders albedo/ normal/ ..., multi-layer EXR frames, XRGB '<name>-albedo.png' files,"
        " or per-channel videos '<name>_Albedo.mp4' ...)"
    )


def load_shot(path: str | Path, *, cache_size: int = 24, **kwargs: Any) -> Shot:
    """Load the shot at `path` lazily, whatever its format.

    Extra keyword arguments go to the format's loader (`normalize_irradiance` for all of them).
    """
    fmt = detect_format(path)
    if fmt == "folder":
        from x2video.io.folder import FolderShot

        return FolderShot(path, cache_size=cache_size, **kwargs)
    if fmt == "video":
        from x2video.io.video import VideoShot

        return VideoShot(path, cache_size=cache_size, **kwargs)
    if fmt == "multilayer":
        from x2video.io.multilayer import MultilayerShot

        return MultilayerShot(path, cache_size=cache_size, **kwargs)
    from x2video.io.xrgb import XRGBShot

    return XRGBShot(path, cache_size=cache_size, **kwargs)
