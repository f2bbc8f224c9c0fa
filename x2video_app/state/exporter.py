"""Export of a render: MP4 (H.264, sRGB) and an EXR shot folder (rendered RGB, optionally the edited channels).

Rendered frames are in the model's exposure; `x2video.io.units.OutputUnits` (the same as the CLI's)
takes them to the input's units for EXR and to the chosen exposure for MP4.

Generators: each yields the number of frames written so far, so a superqt generator worker can
drive a progress dialog and stop between frames (`quit()`). Writes are atomic: the MP4 appears
under its name only when complete; the EXR folder writes every image atomically and its
shot.json last (a folder without shot.json is unfinished). An EXR export stopped part way (a full
disk, a cancel, a crash) resumes: the next export of the same frames and edits into the same folder
keeps the whole frames there (`.x2video-export.json` says what they were made of) and writes the
rest. A full disk is a `DiskFullError` naming the folder, the space still needed and what is kept.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from x2video.channels import INTRINSIC
from x2video.io import ShotWriter
from x2video.io.atomic import DiskFullError, is_disk_full, looks_full, write_json_atomic
from x2video.io.units import OutputUnits
from x2video.io.writers import MP4Writer
from x2video.shot import Shot

#: beside an unfinished EXR export: the digest of what its frames were made of (removed when the export finishes)
EXPORT_RECORD = ".x2video-export.json"


def export_mp4(frames: dict[int, np.ndarray], path: Path, fps: float, units: OutputUnits | None = None) -> Iterator[int]:
    """Rendered linear RGB frames (any order in the dict) -> H.264 MP4 in frame order, tone-mapped at `units`' exposure."""
    units = units if units is not None else OutputUnits()
    order = sorted(frames)
    w = MP4Writer(path, fps, encode="srgb")
    try:
        for k, t in enumerate(order):
            w.write(units.display(frames[t]))
            yield k + 1
        w.close()
    except OSError as exc:
        w.abort(exc)
        if not (is_disk_full(exc) or looks_full(path.parent, 1 << 16)):
            raise
        h, wd = frames[order[0]].shape[:2]
        raise DiskFullError(path.parent, int(h * wd * 1.5 * len(order)), at_most=True, what=f"encoding {path.name} from {len(order)} frames",
                            kept=f"nothing was written to {path} (it appears only when complete)") from None
    except BaseException as exc:  # includes GeneratorExit when the worker is told to quit
        w.abort(exc if isinstance(exc, Exception) else None)
        raise


def export_exr(frames: dict[int, np.ndarray], out_dir: Path, shot: Shot, edits: Any = None, units: OutputUnits | None = None,
               exact: dict[int, np.ndarray] | None = None) -> Iterator[int]:
    """A shot folder: `rgb/` = the render (linear, half), plus the edited intrinsic channels when `edits` is given,
    all in the input's units (irradiance too: shot.json then says it is not normalised, as the input was not).
    `exact`: frames already in the input's units (`RenderState.exact`: a render over the shot's path-traced frames),
    written as they are in place of `frames`' (float16 in the model's exposure), so that pixels no edit reached come
    back as the input's own."""
    from x2video.conditioning.edited import apply_edits

    units = units if units is not None else OutputUnits.for_shot(shot)

    n = len(frames)
    if sorted(frames) != list(range(n)) or n != shot.num_frames:
        raise ValueError(f"EXR export needs every frame of the shot rendered ({len(frames)} of {shot.num_frames})")
    extra = {**shot.info.extra, "x2video:rendered": True, "x2video:irradiance_scale": units.irradiance_scale}
    info = dataclasses.replace(shot.info, channels=("rgb",), source=str(out_dir), extra=extra, irradiance_scale=1.0)
    out_dir = Path(out_dir)
    key = export_key(frames, shot, edits, units)
    record = out_dir / EXPORT_RECORD
    names = ["rgb", *([c for c in INTRINSIC if apply_edits(shot, edits, 0).channels.get(c) is not None] if edits is not None else [])]
    keep = _kept_frames(out_dir, record, key, names, n)
    with ShotWriter(out_dir, info, overwrite=not keep, irradiance_normalized=units.irradiance_scale == 1.0) as w:
        write_json_atomic(record, {"key": key, "channels": names})
        for t in range(n):
            if t in keep:
                w.adopt(t, names)
                yield t + 1
                continue
            rgb = exact.get(t) if exact else None
            chans: dict[str, np.ndarray] = {"rgb": units.scene(frames[t]) if rgb is None else rgb}
            if edits is not None:
                cond = apply_edits(shot, edits, t)
                chans.update({c: a for c in INTRINSIC if (a := cond.channels.get(c)) is not None})
                if "irradiance" in chans:
                    chans["irradiance"] = units.scene(chans["irradiance"])
            try:
                w.write_frame(t, chans)
            except OSError as exc:
                if not (is_disk_full(exc) or looks_full(out_dir, sum(a.size * 2 for a in chans.values()))):
                    raise
                sizes = [p.stat().st_size for c in names for p in (out_dir / c).glob("[0-9]*.exr")]
                each = sum(sizes) / max(1, len(sizes)) * len(names) if sizes else sum(a.size * 2 for a in chans.values())
                raise DiskFullError(out_dir, int(each * (n - t)), what=f"exporting frame {t}, {n - t} of {n} frames still to write",
                                    kept=f"the {t} frame(s) written stay whole there (no shot.json yet: unfinished); free space and "
                                         "export into the same folder again to resume") from None
            yield t + 1
    record.unlink(missing_ok=True)


def export_key(frames: dict[int, np.ndarray], shot: Shot, edits: Any, units: OutputUnits) -> str:
    """A digest of what an EXR export writes: the rendered frames, the edits (their arrays too), the units."""
    h = hashlib.sha256()
    for t in sorted(frames):
        h.update(np.ascontiguousarray(frames[t], np.float32).tobytes())
    if edits is not None:
        h.update(json.dumps(edits.to_dict(), sort_keys=True, default=str).encode())
        for name, arrays in sorted(edits.mask_arrays().items()):
            for t, a in sorted(arrays.items()):
                h.update(f"{name}/{t}".encode())
                h.update(np.ascontiguousarray(a, np.float32).tobytes())
    h.update(json.dumps([shot.info.source, shot.size, units.irradiance_scale, units.exr_attributes()], default=str).encode())
    return h.hexdigest()[:20]


def _kept_frames(out_dir: Path, record: Path, key: str, names: list[str], n: int) -> set[int]:
    """Frames an interrupted export of the same `key` left whole in `out_dir` (none when it finished or made others)."""
    if (out_dir / "shot.json").exists():
        return set()
    try:
        doc = json.loads(record.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return set()
    if not isinstance(doc, dict) or doc.get("key") != key or doc.get("channels") != names:
        return set()
    from x2video.io.image import read_image

    for c in names:  # temporaries a killed write left (whole images are renamed in, never half ones)
        for p in (out_dir / c).glob(".*.tmp.exr"):
            p.unlink(missing_ok=True)
    keep = set()
    for t in range(n):
        try:
            for c in names:
                read_image(out_dir / c / f"{t:06d}.exr")
        except (OSError, ValueError):
            continue
        keep.add(t)
    return keep
