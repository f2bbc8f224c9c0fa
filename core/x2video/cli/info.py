"""`x2video info SHOT`: frames, size, channels present, value ranges and problems found.

Exit status: 0 when no problems were found, 1 when the report lists some (a file that cannot be
read, NaN/Inf values, ...), 2 when the shot cannot be loaded at all; `--json` prints the same
report for scripts. Notes (pixels without a normal: background) are reported but are no problem.
"""
from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from x2video.channels import INTRINSIC


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("info", help="describe a shot: frames, size, channels, value ranges, problems")
    p.add_argument("shot", type=Path, help="shot folder, multi-layer EXR (folder or file), or XRGB set")
    p.add_argument("--frames", type=int, default=8, help="scan this many evenly spaced frames for ranges (0 = all; default 8)")
    p.add_argument("--json", action="store_true", help="print the report as JSON (the exit status is the same: 1 when it lists problems)")
    p.set_defaults(func=run)


def inspect(path: Path, frames: int = 8, progress: Any = None) -> dict[str, Any]:
    """The report `x2video info` prints, as a dict (ranges over the scanned frames; problems as text)."""
    from x2video.io import detect_format, load_shot

    problems: list[str] = []
    notes: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fmt = detect_format(path)
        shot = load_shot(path)
        n = shot.num_frames
        ts = list(range(n)) if frames <= 0 or frames >= n else sorted({int(round(v)) for v in np.linspace(0, n - 1, frames)})
        ranges: dict[str, list[float]] = {}
        for i, t in enumerate(ts):
            for c in (*shot.channels, *shot.info.channel_frames):
                if not shot.has(c, t):  # a keyframe shot's G-buffer frame: no rgb, no light passes
                    continue
                try:
                    a = shot.channel(c, t)
                except (ValueError, OSError) as exc:
                    problems.append(str(exc))
                    continue
                lo, hi = float(a.min()), float(a.max())
                r = ranges.setdefault(c, [lo, hi])
                r[0], r[1] = min(r[0], lo), max(r[1], hi)
                if c == "normal":
                    norms = np.linalg.norm(a, axis=-1)
                    zero = int((norms < 0.5).sum())
                    if zero:
                        notes.append(f"frame {t}: {zero} pixel(s) without a normal (zero vector: background?)")
            if progress is not None:
                progress(i, len(ts))
        problems += [str(w.message) for w in caught]
    missing = [c for c in INTRINSIC if c not in shot.channels]
    info = shot.info
    notes += [partial_note(c, frames, shot.keyframes) for c, frames in info.channel_frames.items()]
    return {
        "path": str(path),
        "format": fmt,
        "frames": n,
        "width": info.width,
        "height": info.height,
        "fps": info.fps,
        "channels": list(shot.channels),
        "dropped": missing,
        "motion": bool(getattr(shot, "_motion", None)),
        "poses": info.poses is not None,
        "keyframes": None if info.rgb_frames is None else list(info.rgb_frames),
        "channel_frames": {c: list(frames) for c, frames in info.channel_frames.items()},
        "irradiance_scale": info.irradiance_scale,
        "caption": info.caption,
        "objects": {str(k): v for k, v in info.object_captions.items()},
        "scanned_frames": ts,
        "ranges": ranges,
        "problems": problems,
        "notes": notes,
    }


def partial_note(channel: str, frames: tuple[int, ...], keyframes: tuple[int, ...], most: int = 12) -> str:
    """'irradiance is on the keyframes only: read there (the frames between hold G-buffer passes)', for a channel that
    only `frames` carry (`ShotInfo.channel_frames`)."""
    if tuple(frames) == tuple(keyframes):
        return f"{channel} is on the keyframes only: read there (the frames between hold G-buffer passes)"
    listed = ", ".join(str(f) for f in frames[:most]) + (f", ... ({len(frames) - most} more)" if len(frames) > most else "")
    return f"{channel} is on frames {listed} only ({len(frames)} frames): read there, missing on the others"


def keyframes_line(keys: list[int], frames: int, most: int = 32) -> str:
    """'keyframes: 0, 8, 16 (3 of 17 frames carry rgb)': the frames of a keyframe shot that carry path-traced rgb."""
    listed = ", ".join(str(k) for k in keys[:most]) + (f", ... ({len(keys) - most} more)" if len(keys) > most else "")
    return f"keyframes: {listed} ({len(keys)} of {frames} frames carry rgb)"


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    bar = tqdm(desc="scanning", unit="frame", leave=False, disable=args.json)
    def progress(i: int, total: int) -> None:
        bar.total = total
        bar.update(1)

    report = inspect(args.shot, args.frames, progress)
    bar.close()
    status = 1 if report["problems"] else 0
    if args.json:
        print(json.dumps(report, indent=1))
        return status
    print(f"{report['path']}  ({report['format']})")
    print(f"  frames   {report['frames']}  at {report['fps']:g} fps, {report['width']}x{report['height']}")
    print(f"  channels {', '.join(report['channels'])}" + (f"  (dropped: {', '.join(report['dropped'])})" if report["dropped"] else ""))
    if report["keyframes"] is not None:
        print(f"  {keyframes_line(report['keyframes'], report['frames'])}")
    scale = report["irradiance_scale"]
    print(f"  poses    {'yes' if report['poses'] else 'no'}   irradiance scale {scale:.4g}"
          + ("" if scale == 1.0 else " (the model sees irradiance x this; renders are written back in the file's units)"))
    if report["caption"]:
        print(f"  caption  {report['caption']}")
    for k, v in report["objects"].items():
        print(f"  object {k}: {v}")
    print(f"  value ranges over {len(report['scanned_frames'])} frame(s):")
    for c, (lo, hi) in report["ranges"].items():
        print(f"    {c:<11s} {lo:10.4g} .. {hi:<10.4g}")
    if report["problems"]:
        print(f"  problems ({len(report['problems'])}):")
        for p in report["problems"][:50]:
            print(f"    - {p}")
    else:
        print("  problems: none found")
    for note in report["notes"][:20]:
        print(f"  note: {note}")
    return status
