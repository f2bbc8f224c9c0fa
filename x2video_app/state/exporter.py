"""Export of a render: MP4 (H.264, sRGB) and an EXR folder (rendered RGB, optionally the edited channels).

Both go through the CLI's writer, `x2video.render.frames.FrameSink`, so an export and `x2video render --out` of
the same shot write the same files: `000000.exr`... (`write_exr_frame`: R, G, B half float in the input's units,
`x2video.io.units.OutputUnits`), or an MP4 tone-mapped at the chosen exposure. With the edits, the edited intrinsic
channels go beside the frames as a shot folder, `channels/` (`load_shot` reads it back).

Generators: each yields the number of frames written so far, so a superqt generator worker can drive a progress
dialog and stop between frames (`quit()`). Writes are atomic: the MP4 or the folder appears under its name only
when complete. An EXR export stopped part way (a full disk, a cancel, a crash) resumes by the CLI's rule: its
frames stay staged in `.NAME.resume` beside the folder, and the next export of the same frames and edits into
the same folder keeps them (with their channels, each written before its frame) and writes the rest. A full disk
is a `DiskFullError` naming the folder, the space still needed and what is kept.
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
from x2video.io.atomic import is_disk_full, looks_full
from x2video.io.units import OutputUnits
from x2video.render.frames import CHANNELS_FOLDER, FrameSink
from x2video.shot import Shot

#: what a full disk's message tells the editor's user to do to resume
RETRY = "export into the same folder again"


def export_mp4(frames: dict[int, np.ndarray], path: Path, fps: float, units: OutputUnits | None = None) -> Iterator[int]:
    """Rendered linear RGB frames (any order in the dict) -> H.264 MP4 in frame order, tone-mapped at `units`' exposure."""
    order = sorted(frames)
    with FrameSink(path, fps=fps, expected=order, units=units) as sink:
        for k, t in enumerate(order):
            sink.add(t, frames[t])
            yield k + 1
        sink.finish()


def export_exr(frames: dict[int, np.ndarray], out_dir: Path, shot: Shot, edits: Any = None, units: OutputUnits | None = None,
               exact: dict[int, np.ndarray] | None = None) -> Iterator[int]:
    """`out_dir/000000.exr`...: the render as the CLI writes it, plus, when `edits` is given, the edited intrinsic
    channels in `out_dir/channels/` (a shot folder, in the input's units: irradiance too, so its shot.json says it is
    not normalised when the input was not). `exact`: frames already in the input's units (`RenderState.exact`: a render
    over the shot's path-traced frames), written as they are in place of `frames`' (float16 in the model's exposure),
    so that pixels no edit reached come back as the input's own."""
    from x2video.conditioning.edited import apply_edits

    units = units if units is not None else OutputUnits.for_shot(shot)
    n = len(frames)
    if sorted(frames) != list(range(n)) or n != shot.num_frames:
        raise ValueError(f"EXR export needs every frame of the shot rendered ({len(frames)} of {shot.num_frames})")
    out_dir = Path(out_dir)
    names = [c for c in INTRINSIC if apply_edits(shot, edits, 0).channels.get(c) is not None] if edits is not None else []
    with FrameSink(out_dir, expected=list(range(n)), units=units, resume=export_key(frames, shot, edits, units, exact), retry=RETRY) as sink:
        channels = _channel_writer(sink.staging / CHANNELS_FOLDER, out_dir / CHANNELS_FOLDER, shot, names, units) if names else None
        for t in range(n):
            if channels is not None and t in sink.kept:
                channels.adopt(t, names)  # written before its frame: a kept frame has them
            elif channels is not None:
                cond = apply_edits(shot, edits, t)
                chans = {c: cond.channels[c] for c in names}
                if "irradiance" in chans:
                    chans["irradiance"] = units.scene(chans["irradiance"])
                try:
                    channels.write_frame(t, chans)
                except OSError as exc:
                    if not (is_disk_full(exc) or looks_full(sink.staging, sum(a.size * 2 for a in chans.values()))):
                        raise
                    raise sink.disk_full(f"frame {t}'s edited channels", frames[t]) from None
            rgb = exact.get(t) if exact else None
            if rgb is None:
                sink.add(t, frames[t])
            else:
                sink.add(t, rgb, in_units=True)
            yield t + 1
        if channels is not None:
            channels.close()
        sink.finish()


def _channel_writer(folder: Path, final: Path, shot: Shot, names: list[str], units: OutputUnits) -> ShotWriter:
    """The shot folder of the edited channels, staged in `folder` (it becomes `final`); an earlier export's temporaries there
    (a killed write leaves them; whole images are renamed in, never half ones) are removed."""
    for p in folder.glob("*/.*.tmp.exr"):
        p.unlink(missing_ok=True)
    extra = {**shot.info.extra, "x2video:irradiance_scale": units.irradiance_scale}
    info = dataclasses.replace(shot.info, channels=tuple(names), source=str(final), extra=extra, irradiance_scale=1.0)
    return ShotWriter(folder, info, irradiance_normalized=units.irradiance_scale == 1.0)


def export_key(frames: dict[int, np.ndarray], shot: Shot, edits: Any, units: OutputUnits,
               exact: dict[int, np.ndarray] | None = None) -> str:
    """A digest of what an EXR export writes: the rendered frames (the exact ones where given), the edits (their arrays
    too), the units."""
    h = hashlib.sha256()
    for t in sorted(frames):
        if exact and t in exact:
            h.update(b"exact")
            h.update(np.ascontiguousarray(exact[t], np.float32).tobytes())
        else:
            h.update(np.ascontiguousarray(frames[t], np.float32).tobytes())
    if edits is not None:
        h.update(json.dumps(edits.to_dict(), sort_keys=True, default=str).encode())
        for name, arrays in sorted(edits.mask_arrays().items()):
            for t, a in sorted(arrays.items()):
                h.update(f"{name}/{t}".encode())
                h.update(np.ascontiguousarray(a, np.float32).tobytes())
    h.update(json.dumps([shot.info.source, shot.size, units.irradiance_scale, units.exr_attributes()], default=str).encode())
    return h.hexdigest()[:20]
