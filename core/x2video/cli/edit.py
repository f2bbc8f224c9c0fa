"""`x2video edit SHOT PROJECT OUT`: apply a project file's edits and write the edited channels."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from x2video.channels import INTRINSIC
from x2video.shot import Shot, ShotInfo


class EditedShot(Shot):
    """`shot` seen through `apply_edits`: edited intrinsic channels (dropped ones absent); the extra
    channels (ids, rgb, depth) pass through unchanged. Reads lazily, one frame's edits at a time.
    The edited irradiance is in the source's normalised exposure, so `irradiance_scale` is the
    source's: writers undo it (units in = units out)."""

    def __init__(self, shot: Shot, edits):
        from x2video.conditioning.edited import apply_edits

        self._shot, self._edits, self._apply = shot, edits, apply_edits
        edits.validate()
        kept = tuple(c for c in shot.channels if not (c in INTRINSIC and c in edits.dropped))
        i = shot.info
        self.info = ShotInfo(
            num_frames=i.num_frames, height=i.height, width=i.width, channels=kept, fps=i.fps, caption=i.caption,
            object_captions=dict(i.object_captions), poses=i.poses, irradiance_scale=i.irradiance_scale, source=f"{i.source} (edited)",
            extra=dict(i.extra),
        )
        self._last: tuple[int, dict[str, np.ndarray | None]] | None = None

    def _read(self, name: str, t: int) -> np.ndarray:
        if name not in INTRINSIC:
            return self._shot.channel(name, t)
        if self._last is None or self._last[0] != t:
            self._last = (t, self._apply(self._shot, self._edits, t).channels)
        a = self._last[1][name]
        assert a is not None
        return a


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("edit", help="apply a project file's edits to a shot and write the edited channels")
    p.add_argument("shot", type=Path, help="input shot")
    p.add_argument("project", type=Path, help="project file (x2video-project JSON)")
    p.add_argument("out", type=Path, help="output folder (or .mp4)")
    p.add_argument("--format", choices=("folder", "multilayer", "png", "mp4"), help="output format (default: folder, mp4 for .mp4)")
    p.add_argument("--channel", help="mp4: channel to show (default albedo)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from x2video.cli.convert import write
    from x2video.edits import load_project
    from x2video.io import load_shot

    project = load_project(args.project)
    shot = load_shot(args.shot)
    edited = EditedShot(shot, project.edits)
    fmt = args.format or ("mp4" if args.out.suffix.lower() == ".mp4" else "folder")
    channel = args.channel or ("albedo" if edited.has("albedo") else None)
    with tqdm(total=shot.num_frames, desc="edit", unit="frame") as bar:
        out = write(edited, args.out, fmt, channel=channel, overwrite=args.overwrite, progress=lambda t: bar.update(1))
    print(f"wrote {out}")
    return 0
