"""Our shot folder (docs/SHOT_FORMAT.md): `ShotWriter` writes one frame by frame, `write_shot_folder` a whole shot;
`x2video.io.load_shot` reads it back lazily as a `FolderShot`. The JSON documents beside the frames are
`x2video.io.metadata`'s.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from x2video.channels import SPECS
from x2video.io.atomic import write_json_atomic
from x2video.io.image import write_exr
from x2video.io.metadata import cameras_json, shot_json
from x2video.shot import Shot, ShotInfo

#: channels a shot folder may hold, with their EXR component names and pixel type
FOLDER_CHANNELS: dict[str, tuple[tuple[str, ...], str]] = {
    **{name: (spec.suffixes, "uint" if name == "ids" else ("float" if name == "depth" else "half")) for name, spec in SPECS.items()},
    "motion": (("X", "Y"), "float"),
}


def frame_name(t: int, ext: str = ".exr") -> str:
    return f"{t:06d}{ext}"


class ShotWriter:
    """Writes a shot folder frame by frame; `close()` (or leaving the `with` block) writes the metadata.

    >>> with ShotWriter("out/shot", info) as w:
    ...     for t in range(info.num_frames):
    ...         w.write_frame(t, {"albedo": a, "normal": n, "ids": ids, "motion": flow})

    Arrays are in memory convention (float32 (H, W, C), int for ids, (H, W) accepted for one
    component); "motion" is (H, W, 2) float32 pixels to frame t+1 (NaN allowed) and may be
    omitted on the last frame. Every image is written atomically; shot.json and cameras.json
    (from `info.poses`, when present) are written last, so a folder without shot.json is an
    unfinished one. `close()` checks every written channel has all its frames.
    """

    def __init__(self, out_dir: str | Path, info: ShotInfo, *, irradiance_normalized: bool = True, overwrite: bool = False):
        self.out_dir = Path(out_dir)
        self.info = info
        self.irradiance_normalized = irradiance_normalized
        if info.num_frames <= 0 or info.height <= 0 or info.width <= 0:
            raise ValueError(f"ShotWriter: info needs positive num_frames/height/width, got {info.num_frames}/{info.height}/{info.width}")
        if info.poses is not None and len(info.poses) != info.num_frames:
            raise ValueError(f"ShotWriter: info.poses has {len(info.poses)} poses for {info.num_frames} frames")
        if (self.out_dir / "shot.json").exists() and not overwrite:
            raise ValueError(f"{self.out_dir}: already holds a shot (shot.json); pass overwrite=True to replace it")
        if overwrite and self.out_dir.is_dir():
            self._clear()  # also the frames of an unfinished earlier run
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self._written: dict[str, set[int]] = {}
        self._closed = False

    def _clear(self) -> None:
        (self.out_dir / "shot.json").unlink(missing_ok=True)
        (self.out_dir / "cameras.json").unlink(missing_ok=True)
        for name in FOLDER_CHANNELS:
            d = self.out_dir / name
            if d.is_dir():
                for p in d.glob("[0-9][0-9][0-9][0-9][0-9][0-9].exr"):
                    p.unlink()

    def write_frame(self, t: int, channels: Mapping[str, np.ndarray]) -> None:
        """Write the given channels of frame `t` (one EXR per channel)."""
        if self._closed:
            raise ValueError(f"{self.out_dir}: ShotWriter already closed")
        if not 0 <= t < self.info.num_frames:
            raise IndexError(f"frame {t} outside the shot's {self.info.num_frames} frames")
        for name, arr in channels.items():
            if name not in FOLDER_CHANNELS:
                raise ValueError(f"frame {t}: unknown channel {name!r} (one of {', '.join(FOLDER_CHANNELS)})")
            suffixes, ptype = FOLDER_CHANNELS[name]
            a = np.asarray(arr)
            if a.ndim == 2:
                a = a[..., None]
            want = (self.info.height, self.info.width, len(suffixes))
            if a.shape != want:
                raise ValueError(f"frame {t}: channel {name!r} has shape {a.shape}, expected {want}")
            if ptype == "uint":
                if a.dtype.kind == "f":
                    a = np.rint(a)
                if a.min(initial=0) < 0:
                    raise ValueError(f"frame {t}: channel {name!r} has negative object ids")
            planes = {s: a[..., i] for i, s in enumerate(suffixes)}
            attrs = {"x2video:frame": int(t), "x2video:channel": name}
            write_exr(self.out_dir / name / frame_name(t), planes, ptype, attrs)
            self._written.setdefault(name, set()).add(t)

    def adopt(self, t: int, names: Iterable[str]) -> None:
        """Count channels `names` of frame `t` as written: whole files an interrupted earlier writer left (each image is
        written atomically), which a resumed export keeps instead of writing again."""
        for name in names:
            if not (self.out_dir / name / frame_name(t)).is_file():
                raise ValueError(f"{self.out_dir}: frame {t} of channel {name!r} is not there to keep")
            self._written.setdefault(name, set()).add(t)

    def close(self) -> None:
        """Check completeness, then write shot.json and cameras.json atomically."""
        if self._closed:
            return
        n = self.info.num_frames
        for name, done in self._written.items():
            need = set(range(n - 1)) if name == "motion" else set(range(n))
            missing = sorted(need - done)
            if missing:
                raise ValueError(f"{self.out_dir}: channel {name!r} is missing frame(s) {missing[:5]}{'...' if len(missing) > 5 else ''}")
        if not self._written:
            raise ValueError(f"{self.out_dir}: no frames were written")
        if self.info.poses is not None:
            write_json_atomic(self.out_dir / "cameras.json", cameras_json(self.info.poses))
        write_json_atomic(self.out_dir / "shot.json", shot_json(self.info, self.irradiance_normalized))
        self._closed = True

    def __enter__(self) -> "ShotWriter":
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()


def write_shot_folder(shot: Shot, out_dir: str | Path, *, overwrite: bool = False, progress: Any = None) -> Path:
    """Copy every frame of `shot` (and its motion, when it has some) into a shot folder.

    Units in = units out: irradiance is written in the input's units (the loader's exposure
    normalisation undone, `x2video.io.units`), and shot.json says it is normalised only when the
    input was (scale 1), so loading the copy gives what loading the original gave."""
    from x2video.io.units import OutputUnits

    info = shot.info
    units = OutputUnits.for_shot(shot)
    normalized = units.irradiance_scale == 1.0
    with ShotWriter(out_dir, info, irradiance_normalized=normalized, overwrite=overwrite) as w:
        motion = getattr(shot, "motion", None)
        for t in range(info.num_frames):
            frame = shot.frame(t)
            if "irradiance" in frame:
                frame["irradiance"] = units.scene(frame["irradiance"])
            if callable(motion) and t < info.num_frames - 1:
                m = motion(t)
                if m is not None:
                    frame["motion"] = m
            w.write_frame(t, frame)
            if progress is not None:
                progress(t)
    return Path(out_dir)
