"""Writers: multi-layer EXR sequences, PNG sequences, and MP4 (H.264, yuv420p, sRGB) through PyAV, all atomic.

(The EXR sequence in our shot-folder layout is `x2video.io.shotdir.write_shot_folder`.)
Every function takes an optional `progress(t)` callback; none prints.
"""
from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from x2video.channels import SPECS, linear_to_srgb, tonemap
from x2video.io.atomic import atomic_path, write_json_atomic
from x2video.io.image import write_exr, write_ldr
from x2video.io.metadata import cameras_json, shot_json
from x2video.io.shotdir import frame_name
from x2video.io.units import OutputUnits
from x2video.shot import Shot

Progress = Callable[[int], None] | None


def _prepare(out_dir: str | Path, overwrite: bool) -> Path:
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise ValueError(f"{out}: output folder is not empty (use overwrite)")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _metadata(shot: Shot, out: Path, irradiance_normalized: bool = True) -> None:
    if shot.info.poses is not None:
        write_json_atomic(out / "cameras.json", cameras_json(shot.info.poses))
    write_json_atomic(out / "shot.json", shot_json(shot.info, irradiance_normalized=irradiance_normalized))


def write_multilayer(shot: Shot, out_dir: str | Path, *, overwrite: bool = False, progress: Progress = None) -> Path:
    """One half-float multi-layer EXR per frame with our names (``albedo.R`` ...); ids and depth as float.
    Irradiance in the input's units (the loader's exposure normalisation undone, as `write_shot_folder`)."""
    out = _prepare(out_dir, overwrite)
    motion = getattr(shot, "motion", None)
    units = OutputUnits.for_shot(shot)
    normalized = units.irradiance_scale == 1.0
    for t in range(shot.num_frames):
        planes: dict[str, np.ndarray] = {}
        types: dict[str, str] = {}
        frame = shot.frame(t)
        if "irradiance" in frame:
            frame["irradiance"] = units.scene(frame["irradiance"])
        if callable(motion) and (m := motion(t)) is not None:
            frame["motion"] = m
        for name, a in frame.items():
            suffixes = SPECS[name].suffixes if name in SPECS else ("X", "Y")
            for i, s in enumerate(suffixes):
                planes[f"{name}.{s}"] = a[..., i].astype(np.float32)
                types[f"{name}.{s}"] = "float" if name in ("ids", "depth", "motion") else "half"
        attrs = {"x2video:frame": t, "x2video:irradiance_normalized": int(normalized), "FramesPerSecond": float(shot.info.fps)}
        write_exr(out / frame_name(t), planes, types, attrs)
        if progress is not None:
            progress(t)
    _metadata(shot, out, normalized)
    return out


def to_display(name: str, a: np.ndarray) -> np.ndarray:
    """float32 (H, W, 3) in [0, 1] showing channel `name` of one frame (sRGB-encoded where colour)."""
    if name in ("rgb", "irradiance"):
        return tonemap(a)
    if name == "albedo":
        return linear_to_srgb(a)
    if name == "normal":
        return np.clip(a * 0.5 + 0.5, 0, 1).astype(np.float32)
    if name == "ids":
        ids = a[..., 0].astype(np.uint32)
        h = (ids * np.uint32(2654435761)) >> np.uint32(8)  # hash ids to colours, 0 stays black
        rgb = np.stack([(h >> s) & 255 for s in (0, 8, 16)], -1).astype(np.float32) / 255
        return np.where(ids[..., None] == 0, 0, rgb).astype(np.float32)
    if name == "depth":
        d = a[..., 0]
        v = 1 - d / max(float(d.max()), 1e-6)
        return np.repeat(v[..., None], 3, -1).astype(np.float32)
    return np.repeat(np.clip(a[..., :1], 0, 1), 3, -1).astype(np.float32)


def write_png_sequence(
    shot: Shot, out_dir: str | Path, *, bits: int = 16, channels: Iterable[str] | None = None, overwrite: bool = False, progress: Progress = None
) -> Path:
    """A folder per channel of PNGs: albedo/irradiance/rgb sRGB-encoded (irradiance and rgb clipped to
    [0, 1]: lossy for HDR; irradiance stays in the loader's normalised exposure, which is what fits
    8/16-bit, and shot.json says so), normals ``0.5 n + 0.5``, roughness/metallic as is, ids as integers
    (16-bit: up to 65535); depth is not written (no meaningful PNG form)."""
    out = _prepare(out_dir, overwrite)
    names = [c for c in (shot.channels if channels is None else channels) if c != "depth"]
    for c in names:
        if c not in shot.channels:
            raise ValueError(f"shot {shot.info.source!r} has no channel {c!r}")
    for t in range(shot.num_frames):
        for c in names:
            a = shot.channel(c, t)
            if c == "ids":
                if bits != 16 or a.max(initial=0) > 65535:
                    raise ValueError(f"frame {t}: ids need 16-bit PNGs and values <= 65535 (max {int(a.max(initial=0))})")
                data = a.astype(np.uint16)
                write_ldr(out / c / frame_name(t, ".png"), data)
                continue
            if c in ("albedo", "irradiance", "rgb"):
                v = linear_to_srgb(a)
            elif c == "normal":
                v = np.clip(a * 0.5 + 0.5, 0, 1)
            else:
                v = a
            write_ldr(out / c / frame_name(t, ".png"), v, bits=bits)
        if progress is not None:
            progress(t)
    if shot.info.poses is not None:
        write_json_atomic(out / "cameras.json", cameras_json(shot.info.poses))
    doc = shot_json(shot.info, irradiance_normalized=True)
    write_json_atomic(out / "shot.json", doc)
    return out


class MP4Writer:
    """Streams (H, W, 3) frames into an H.264 yuv420p MP4, atomically (the file appears on `close`).

    `encode`: "linear" frames are tone-mapped (`x2video.channels.tonemap`), "srgb" frames in [0, 1]
    are written as they are, uint8 frames always as they are. Odd sizes are padded by one edge
    pixel to even (yuv420p needs even sizes).
    """

    def __init__(self, path: str | Path, fps: float = 10.0, *, crf: int = 18, encode: str = "linear"):
        import av

        if fps <= 0:
            raise ValueError(f"fps must be positive, got {fps}")
        if encode not in ("linear", "srgb"):
            raise ValueError(f"encode must be 'linear' or 'srgb', got {encode!r}")
        self.path = Path(path)
        if self.path.suffix.lower() not in (".mp4", ".mov", ".mkv"):
            raise ValueError(f"{self.path}: MP4 output needs a .mp4 (or .mov/.mkv) name")
        self.encode = encode
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        self._container = av.open(str(self._tmp), mode="w")
        self._stream = self._container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        self._stream.pix_fmt = "yuv420p"
        self._stream.options = {"crf": str(crf), "preset": "veryfast"}
        self._size: tuple[int, int] | None = None
        self.frames = 0
        self._av = av

    def write(self, frame: np.ndarray) -> None:
        a = np.asarray(frame)
        if a.ndim != 3 or a.shape[2] != 3:
            raise ValueError(f"{self.path}: frame {self.frames} has shape {a.shape}, expected (H, W, 3)")
        if a.dtype != np.uint8:
            a = tonemap(a) if self.encode == "linear" else np.clip(np.nan_to_num(a.astype(np.float32)), 0, 1)
            a = np.round(a * 255).astype(np.uint8)
        h, w = a.shape[:2]
        if h % 2 or w % 2:
            a = np.pad(a, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        if self._size is None:
            self._size = a.shape[:2]
            self._stream.height, self._stream.width = self._size
        elif a.shape[:2] != self._size:
            raise ValueError(f"{self.path}: frame {self.frames} is {w}x{h}, earlier frames {self._size[1]}x{self._size[0]}")
        vf = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(a), format="rgb24")
        for packet in self._stream.encode(vf):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> Path:
        if self._container is None:
            return self.path
        try:
            if self.frames == 0:
                raise ValueError(f"{self.path}: no frames written")
            for packet in self._stream.encode():
                self._container.mux(packet)
            self._container.close()
            self._container = None
            self._ctx.__exit__(None, None, None)
        except BaseException as exc:
            self.abort(exc)
            raise
        return self.path

    def abort(self, exc: BaseException | None = None) -> None:
        """Drop the partial file (nothing appears under the final name)."""
        if self._container is not None:
            try:
                self._container.close()
            except Exception:  # noqa: BLE001 - closing a broken container after an error
                pass
            self._container = None
        err = exc or RuntimeError("aborted")
        try:
            self._ctx.__exit__(type(err), err, None)
        except BaseException:  # atomic_path re-raises the error it was given
            pass

    def __enter__(self) -> "MP4Writer":
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort(exc)


def write_mp4(shot: Shot, path: str | Path, *, channel: str = "rgb", fps: float | None = None, crf: int = 18, progress: Progress = None) -> Path:
    """Encode one channel of `shot` (display form, see `to_display`) as an MP4."""
    if channel not in shot.channels:
        raise ValueError(f"shot {shot.info.source!r} has no channel {channel!r} (has {', '.join(shot.channels)})")
    with MP4Writer(path, fps or shot.info.fps, crf=crf, encode="srgb") as w:
        for t in range(shot.num_frames):
            w.write(to_display(channel, shot.channel(channel, t)))
            if progress is not None:
                progress(t)
    return Path(path)
