"""`x2video convert SHOT OUT --format folder|multilayer|png|mp4`: rewrite a shot in another format."""
from __future__ import annotations

import argparse
from pathlib import Path

FORMATS = ("folder", "multilayer", "png", "mp4")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("convert", help="convert a shot between formats (EXR folder, multi-layer EXR, PNG, MP4)")
    p.add_argument("shot", type=Path, help="input shot (any format `x2video info` reads)")
    p.add_argument("out", type=Path, help="output folder (or .mp4 file)")
    p.add_argument("--format", choices=FORMATS, help="output format (default: mp4 when OUT ends in .mp4, else folder)")
    p.add_argument("--channel", default=None, help="mp4: which channel to show (default rgb, else albedo)")
    p.add_argument("--fps", type=float, help="mp4: frame rate (default: the shot's)")
    p.add_argument("--bits", type=int, choices=(8, 16), default=16, help="png: bit depth (default 16)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.set_defaults(func=run)


def write(shot, out: Path, fmt: str, *, channel: str | None = None, fps: float | None = None, bits: int = 16, overwrite: bool = False, progress=None) -> Path:
    """Write `shot` to `out` in format `fmt` (shared by `convert` and `edit`)."""
    from x2video.io import write_shot_folder
    from x2video.io.writers import write_mp4, write_multilayer, write_png_sequence

    if fmt == "mp4":
        if out.exists() and not overwrite:
            raise ValueError(f"{out}: exists (use --overwrite)")
        ch = channel or ("rgb" if shot.has("rgb") else ("albedo" if shot.has("albedo") else shot.channels[0]))
        return write_mp4(shot, out, channel=ch, fps=fps, progress=progress)
    if fmt == "folder":
        if out.exists() and any(out.iterdir()) and not (out / "shot.json").exists():
            raise ValueError(f"{out}: output folder is not empty and holds no shot")
        return write_shot_folder(shot, out, overwrite=overwrite, progress=progress)
    if fmt == "multilayer":
        return write_multilayer(shot, out, overwrite=overwrite, progress=progress)
    if fmt == "png":
        return write_png_sequence(shot, out, bits=bits, overwrite=overwrite, progress=progress)
    raise ValueError(f"unknown format {fmt!r} (one of {', '.join(FORMATS)})")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from x2video.io import load_shot

    shot = load_shot(args.shot)
    fmt = args.format or ("mp4" if args.out.suffix.lower() == ".mp4" else "folder")
    with tqdm(total=shot.num_frames, desc=f"convert to {fmt}", unit="frame") as bar:
        out = write(shot, args.out, fmt, channel=args.channel, fps=args.fps, bits=args.bits, overwrite=args.overwrite, progress=lambda t: bar.update(1))
    print(f"wrote {out}")
    return 0
