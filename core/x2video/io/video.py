"""`VideoShot`: one video per channel (V-RGBX / DiffusionRenderer style), decoded lazily with PyAV.

Files ``<name>_<Channel>.<ext>`` (also ``<name>.<channel>.<ext>`` or ``<name>-<channel>.<ext>``),
ext one of .mp4 .mov .mkv .avi .webm, channel matched ignoring case:

- Albedo / basecolor / base_color / diffuse_albedo -> albedo (8-bit sRGB, decoded to linear)
- Normal / normals -> normal (``2v - 1``, normalised)
- Material -> roughness (R) and metallic (G), values as stored
- Roughness, Metallic / metalness -> one channel (R)
- Irradiance / shading -> irradiance (8-bit sRGB, decoded to linear; exposure normalised once per shot)
- RGB / image / beauty -> rgb

Every video must have the same frame count and size. Frames are decoded forward and kept in a
small LRU cache; going back (or far ahead) seeks to the keyframe before the frame and decodes
forward from there. Poses come from cameras.json or transforms.json beside the videos.
"""
from __future__ import annotations

import logging
import re
import threading
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from x2video.channels import SPECS
from x2video.io.cache import LRU
from x2video.io.convention import exposure_scale, log_luminance_sum, sanitize, scale_irradiance, to_memory
from x2video.io.image import ImageData
from x2video.io.metadata import find_poses, parse_shot_json
from x2video.shot import Shot, ShotInfo

log = logging.getLogger(__name__)

VIDEO_EXTENSIONS = (".mp4", ".mov", ".mkv", ".avi", ".webm")
#: channel word in a file name (lower case) -> {our channel: component index or None for all}
WORDS: dict[str, dict[str, int | None]] = {
    "albedo": {"albedo": None}, "basecolor": {"albedo": None}, "base_color": {"albedo": None},
    "diffuse_albedo": {"albedo": None},
    "normal": {"normal": None}, "normals": {"normal": None},
    "material": {"roughness": 0, "metallic": 1},
    "roughness": {"roughness": 0}, "metallic": {"metallic": 0}, "metalness": {"metallic": 0},
    "irradiance": {"irradiance": None}, "shading": {"irradiance": None},
    "rgb": {"rgb": None}, "image": {"rgb": None}, "beauty": {"rgb": None},
}
_NAME_RE = re.compile(r"^(?P<prefix>.*?)[_.\-](?P<word>" + "|".join(sorted(WORDS, key=len, reverse=True)) + r")$", re.IGNORECASE)
EXPOSURE_SAMPLES = 16


def channel_videos(folder: Path, prefix: str | None = None) -> dict[str, tuple[Path, int | None]]:
    """Our channel -> (video file, component index or None) for the per-channel videos in `folder`.

    Several shots in one folder (different prefixes) are an error unless `prefix` picks one."""
    found: dict[str, dict[str, tuple[Path, int | None]]] = {}
    if not folder.is_dir():
        return {}
    for p in sorted(folder.iterdir()):
        if not p.is_file() or p.suffix.lower() not in VIDEO_EXTENSIONS or p.name.startswith("."):
            continue
        m = _NAME_RE.match(p.stem)
        if m is None:
            continue
        chans = found.setdefault(m["prefix"], {})
        parts = WORDS[m["word"].lower()]
        for name, comp in parts.items():
            if name in chans:
                other = chans[name][0]
                other_packed = len(WORDS[_NAME_RE.match(other.stem)["word"].lower()]) > 1  # type: ignore[index]
                if other_packed == (len(parts) > 1):
                    raise ValueError(f"{folder}: two videos for {name!r}: {other.name} and {p.name}")
                if not other_packed:
                    continue  # a Roughness / Metallic video of its own wins over the packed Material one
            chans[name] = (p, comp)
    if prefix is not None:
        return found.get(prefix, {})
    if len(found) > 1:
        raise ValueError(f"{folder}: videos of several shots ({', '.join(repr(k) for k in sorted(found))}); "
                         "give one of the files to pick its shot")
    return next(iter(found.values()), {})


def video_prefix(path: Path) -> str | None:
    """The shot prefix of one per-channel video file (``scene_Albedo.mp4`` -> ``scene``), or None."""
    if path.suffix.lower() not in VIDEO_EXTENSIONS:
        return None
    m = _NAME_RE.match(path.stem)
    return None if m is None else m["prefix"]


class _Decoder:
    """Frame access to one video file: decodes forward from where it is, and seeks (to the keyframe
    before, then forward) to go back or far ahead, so scrubbing a long video does not re-decode it
    from the start. Frame index = presentation time x frame rate (constant-rate video). One reader
    at a time (a lock)."""

    #: frames ahead of the decoder that are decoded through rather than sought
    AHEAD = 48

    def __init__(self, path: Path) -> None:
        import av

        self.path = path
        self._av = av
        try:
            with av.open(str(path)) as c:
                if not c.streams.video:
                    raise ValueError(f"{path}: no video stream")
                s = c.streams.video[0]
                self.width, self.height = s.codec_context.width, s.codec_context.height
                rate = s.average_rate or s.guessed_rate
                self.fps = float(rate) if rate else 10.0
                self._time_base = s.time_base
                n = s.frames
                if not n:  # container without a frame count: count the packets that hold frames
                    n = sum(1 for pkt in c.demux(s) if pkt.size > 0)
                    c.seek(0)
                self.num_frames = int(n)
                first = next(c.decode(video=0), None)
                self._start = None if first is None or first.pts is None or rate is None else first.pts
        except av.error.FFmpegError as exc:
            raise ValueError(f"{path}: cannot read the video ({exc})") from None
        self._container: Any = None
        self._frames: Any = None
        self._next = 0
        self._lock = threading.Lock()

    def read(self, t: int) -> np.ndarray:
        """uint8 (H, W, 3) RGB of frame t."""
        with self._lock:
            try:
                return self._read(t)
            except self._av.error.FFmpegError as exc:
                raise ValueError(f"{self.path}: frame {t} cannot be decoded ({exc})") from None

    def _index(self, frame: Any) -> int | None:
        if self._start is None or frame.pts is None:
            return None
        return int(round(float((frame.pts - self._start) * self._time_base) * self.fps))

    def _open(self) -> None:
        self.close()
        self._container = self._av.open(str(self.path))
        self._frames = self._container.decode(video=0)
        self._next = 0

    def _read(self, t: int) -> np.ndarray:
        if self._container is None or not self._next <= t <= self._next + self.AHEAD:
            if self._container is None or t < self.AHEAD or self._start is None:
                self._open()
            else:  # seek to the keyframe at or before t, then decode forward
                s = self._container.streams.video[0]
                self._container.seek(self._start + int(round(t / self.fps / self._time_base)), stream=s, backward=True)
                self._frames = self._container.decode(s)
                self._next = -1  # unknown until a frame says
        for frame in self._frames:
            i = self._index(frame)
            if i is None and self._next < 0:  # after a seek a frame without a time cannot be placed
                self._open()
                return self._read_from_start(t)
            i = self._next if i is None or self._next >= 0 and i < self._next else i
            self._next = i + 1
            if i == t:
                return frame.to_ndarray(format="rgb24")
            if i > t:  # the seek landed past t: decode from the start instead
                self._open()
                return self._read_from_start(t)
        raise ValueError(f"{self.path}: frame {t} missing (the video has {self._next} decodable frames)")

    def _read_from_start(self, t: int) -> np.ndarray:
        for i, frame in enumerate(self._frames):
            self._next = i + 1
            if i == t:
                return frame.to_ndarray(format="rgb24")
        raise ValueError(f"{self.path}: frame {t} missing (the video has {self._next} decodable frames)")

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
            self._container = None


class VideoShot(Shot):
    """A shot held as one video per channel (see the module docstring), read lazily.

    path: the folder holding the videos, or one of them (which picks its shot among several).
    normalize_irradiance: None = as shot.json beside the videos says (`irradiance_normalized`), else
        force on/off; on = the XRGB exposure factor, once per shot, in `info.irradiance_scale`.
    """

    def __init__(self, path: str | Path, *, cache_size: int = 24, normalize_irradiance: bool | None = None):
        p = Path(path)
        folder, prefix = (p.parent, video_prefix(p)) if p.is_file() else (p, None)
        if p.is_file() and prefix is None:
            raise ValueError(f"{p}: not a per-channel video (expected <name>_Albedo.mp4, <name>_Normal.mp4, ...)")
        self._sources = channel_videos(folder, prefix)
        if not self._sources:
            raise ValueError(f"{p}: no per-channel videos (expected <name>_Albedo.mp4, _Normal, _Material, _Irradiance ...)")
        self._decoders: dict[Path, _Decoder] = {}
        for f, _ in self._sources.values():
            if f not in self._decoders:
                self._decoders[f] = _Decoder(f)
        first = next(iter(self._decoders.values()))
        for d in self._decoders.values():
            if (d.num_frames, d.height, d.width) != (first.num_frames, first.height, first.width):
                raise ValueError(f"{d.path}: {d.num_frames} frames of {d.width}x{d.height}, but {first.path.name} has "
                                 f"{first.num_frames} of {first.width}x{first.height}")
        meta: dict[str, Any] = parse_shot_json(folder / "shot.json") if (folder / "shot.json").is_file() else {}
        n = first.num_frames
        self._cache = LRU(cache_size)
        self.info = ShotInfo(
            num_frames=n,
            height=first.height,
            width=first.width,
            channels=tuple(c for c in SPECS if c in self._sources),
            fps=float(meta.get("fps", round(float(Fraction(first.fps).limit_denominator(1001)), 3))),
            caption=str(meta.get("caption", "")),
            object_captions=dict(meta.get("objects", {})),
            poses=find_poses(folder, n, (first.height, first.width)),
            source=str(p),
            extra={**dict(meta.get("extra", {})), "videos": {k: f.name for k, (f, _) in self._sources.items()}},
        )
        if normalize_irradiance is None:
            normalize_irradiance = not meta.get("irradiance_normalized", False)
        if normalize_irradiance and "irradiance" in self._sources:
            ts = sorted({int(round(i)) for i in np.linspace(0, n - 1, min(n, EXPOSURE_SAMPLES))})
            total, count = 0.0, 0
            for t in ts:
                s, c = log_luminance_sum(self._decode("irradiance", t, 1.0))
                total, count = total + s, count + c
            self.info.irradiance_scale = exposure_scale(total, count)
            log.info("%s: irradiance exposure scale %.4g (measured on %d frames)", p, self.info.irradiance_scale, len(ts))

    def _pixels(self, path: Path, t: int) -> np.ndarray:
        return self._cache.get_or(("video", path, t), lambda: self._decoders[path].read(t))

    def _decode(self, name: str, t: int, scale: float | None = None) -> np.ndarray:
        path, comp = self._sources[name]
        rgb = self._pixels(path, t)  # (H, W, 3) uint8
        where = f"{path} (frame {t})"
        if comp is not None:
            return sanitize(name, rgb[..., comp : comp + 1].astype(np.float32) / 255.0, where)
        planes = {c: rgb[..., i].astype(np.float32) / 255.0 for i, c in enumerate("RGB")}
        img = ImageData(path=str(path), width=rgb.shape[1], height=rgb.shape[0], channel_names=("R", "G", "B"),
                        planes=planes, format="uint8", max_int=255)
        a = to_memory(name, img, where=where)
        return scale_irradiance(name, a, self.info.irradiance_scale if scale is None else scale)

    def _read(self, name: str, t: int) -> np.ndarray:
        return self._cache.get_or((name, t), lambda: self._decode(name, t))
