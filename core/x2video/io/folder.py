"""`FolderShot`: a folder per channel (`albedo/`, `normal/`, ...), frames as EXR/PNG/JPG/TIFF, read lazily.

Covers our own shot folder (docs/SHOT_FORMAT.md, with shot.json/cameras.json) and outside
footage laid out the same way with any `<prefix><number>.<ext>` numbering. Loading reads only
the headers of each channel's first frame; pixels are read when a frame is asked for and kept
in a small LRU cache.
"""
from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

import numpy as np

from x2video.channels import SPECS
from x2video.io.cache import LRU
from x2video.io.convention import exposure_scale, log_luminance_sum, sanitize, scale_irradiance, to_memory, zero_nonfinite
from x2video.io.image import FileStamps, ImageData, read_image, read_spec
from x2video.io.metadata import find_poses, parse_shot_json
from x2video.io.sequence import FRAME_RE, find_frames, numbered_frames
from x2video.shot import Shot, ShotInfo

log = logging.getLogger(__name__)

#: folder names accepted for each channel besides its own name (matched ignoring case, so the
#: V-RGBX layout's Albedo/ Normal/ Irradiance/ and DiffusionRenderer's basecolor/ load as they are)
ALIASES: dict[str, tuple[str, ...]] = {
    "albedo": ("basecolor", "base_color", "diffuse_albedo"),
    "normal": ("normals",),
    "metallic": ("metalness",),
    "irradiance": ("shading",),
    "rgb": ("beauty", "image", "images"),
    "ids": ("id", "object_id"),
}
#: a packed material folder (V-RGBX): roughness in R, metallic in G; used for the channels that
#: have no folder of their own
PACKED = {"material": {"roughness": 0, "metallic": 1}}
#: at most this many frames (evenly spaced) are read to measure a shot's irradiance exposure
EXPOSURE_SAMPLES = 16
#: the path-traced light passes, which a keyframe shot (rgb/ with gaps) may hold on some frames only (its keyframes):
#: their folders may have gaps there, and the frames that carry them are `ShotInfo.channel_frames`
KEYFRAME_PASSES = ("irradiance", "diffuse_color", "glossy", "glossy_color")


#: DiffusionRenderer's G-buffer frames, all in one folder: ``<chunk>.<index>.<pass>.<ext>`` (its
#: inverse renderer's ``gbuffer_frames/<clip>/``); pass name -> our channel. Its depth pass is
#: normalised for display, not metres, so it is not read.
PASS_NAMES = {"basecolor": "albedo", "base_color": "albedo", "diffuse_albedo": "albedo", "normal": "normal",
              "roughness": "roughness", "metallic": "metallic", "irradiance": "irradiance", "rgb": "rgb"}
_PASS_RE = re.compile(r"^(?P<nums>\d+(?:\.\d+)*)\.(?P<pass>[A-Za-z_]+)\.(?P<ext>png|jpe?g|exr|tiff?)$", re.IGNORECASE)


def pass_files(root: Path) -> dict[str, list[Path]]:
    """Channel -> frame files, for a folder of ``<chunk>.<index>.<pass>.<ext>`` files (DiffusionRenderer);
    {} when the folder holds none. Frames are ordered by their numbers; a missing frame, or frames of
    several chunks (DiffusionRenderer's chunks overlap: stitch them first), are errors naming the folder."""
    if not root.is_dir():
        return {}
    found: dict[str, dict[tuple[int, ...], Path]] = {}
    preferred: dict[str, str] = {}
    for p in sorted(root.iterdir()):
        m = _PASS_RE.match(p.name) if p.is_file() else None
        if m is None or m["pass"].lower() not in PASS_NAMES:
            continue
        ch, pas = PASS_NAMES[m["pass"].lower()], m["pass"].lower()
        if ch in preferred and preferred[ch] != pas:  # basecolor wins over diffuse_albedo
            if list(PASS_NAMES).index(pas) > list(PASS_NAMES).index(preferred[ch]):
                continue
            found.pop(ch, None)
        preferred[ch] = pas
        found.setdefault(ch, {})[tuple(int(v) for v in m["nums"].split("."))] = p
    out: dict[str, list[Path]] = {}
    for ch, frames in found.items():
        keys = sorted(frames)
        chunks = sorted({k[:-1] for k in keys})
        if len(chunks) > 1:
            raise ValueError(f"{root}: {preferred[ch]} frames of {len(chunks)} chunks ({', '.join('.'.join(map(str, c)) for c in chunks[:3])}); "
                             "overlapping chunks must be stitched into one sequence first")
        idx = [k[-1] for k in keys]
        if idx != list(range(idx[0], idx[0] + len(idx))):
            gap = next(a + 1 for a, b in zip(idx, idx[1:]) if b != a + 1)
            raise ValueError(f"{root}: {preferred[ch]} frame {gap} is missing")
        out[ch] = [frames[k] for k in keys]
    return out


def channel_folders(root: Path) -> dict[str, Path]:
    """Channel name -> folder, for the channel folders present in `root`."""
    found: dict[str, Path] = {}
    if not root.is_dir():
        return found
    dirs: dict[str, Path] = {}
    for p in sorted(root.iterdir()):
        if p.is_dir() and not p.name.startswith(".") and (p.name.lower() not in dirs or p.name == p.name.lower()):
            dirs[p.name.lower()] = p  # an exact lower-case name wins over Albedo/ALBEDO
    for name in (*SPECS, "motion"):
        for cand in (name, *ALIASES.get(name, ())):
            if cand in dirs:
                found[name] = dirs[cand]
                break
    for pack, parts in PACKED.items():
        if pack in dirs:
            for name in parts:
                found.setdefault(name, dirs[pack])
    return found


class FolderShot(Shot):
    """A lazily read folder-per-channel shot.

    cache_size: how many decoded (channel, frame) arrays to keep (LRU).
    normalize_irradiance: None = as shot.json says (`irradiance_normalized`), else force on/off:
        when on, irradiance is scaled once per shot by the XRGB exposure factor (measured on up to
        EXPOSURE_SAMPLES frames) and `info.irradiance_scale` holds the factor.
    """

    def __init__(self, root: str | Path, *, cache_size: int = 24, normalize_irradiance: bool | None = None):
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"{self.root}: shot folder does not exist")
        folders = channel_folders(self.root)
        meta: dict[str, Any] = {}
        if (self.root / "shot.json").is_file():
            meta = parse_shot_json(self.root / "shot.json")
        passes = {} if folders else pass_files(self.root)
        if not folders and not passes:
            raise ValueError(
                f"{self.root}: no channel folders (expected some of {', '.join((*SPECS, 'motion'))}/ with numbered frames)"
            )
        keyed = folders.get("rgb") if len(folders) > 1 and not passes else None
        # the light passes may have gaps where rgb/ has (a keyframe shot), when another channel numbers the frames
        light = [n for n in KEYFRAME_PASSES if keyed is not None and n in folders
                 and any(m not in (*KEYFRAME_PASSES, "rgb", "motion") for m in folders)]
        self._frames: dict[str, list[Path]] = passes or {name: find_frames(d) for name, d in folders.items()
                                                         if d is not keyed and name not in light}
        rgb_frames = self._keyframes(keyed, meta) if keyed is not None else None
        some: dict[str, tuple[int, ...]] = {}
        for name in light:
            if rgb_frames is not None and None in rgb_frames:
                files = self._keyframes(folders[name], meta)
                if None in files:
                    some[name] = tuple(t for t, f in enumerate(files) if f is not None)
                self._frames[name] = files  # type: ignore[assignment]  (None on frames without the pass)
            else:  # rgb on every frame: so must the light be
                self._frames[name] = find_frames(folders[name])
        #: channel -> component index, for channels read from a packed material folder
        self._packed = {name: PACKED[d.name.lower()][name] for name, d in folders.items() if d.name.lower() in PACKED}
        motion = self._frames.pop("motion", None)
        counts = {name: len(f) for name, f in self._frames.items()}
        if not counts:
            raise ValueError(f"{self.root}: only motion/ found, no image channels")
        first = next(iter(counts))
        n = meta.get("num_frames", counts[first])
        ref_name = "shot.json" if "num_frames" in meta else f"{first}/"
        for name, c in counts.items():
            if c != n:
                where = self.root / folders[name].name if name in folders else f"{self.root} ({name} pass)"
                raise ValueError(f"{where}: {c} frames, but {ref_name} has {n}")
        if motion is not None and len(motion) not in (n, n - 1):
            raise ValueError(f"{folders['motion']}: {len(motion)} motion frames for a shot of {n} frames (expected {n - 1} or {n})")
        if rgb_frames is not None and all(t is not None for t in rgb_frames):
            self._frames["rgb"], rgb_frames = list(rgb_frames), None  # type: ignore[list-item]  (rgb on every frame)
        elif rgb_frames is not None:
            self._frames["rgb"] = rgb_frames  # type: ignore[assignment]  (None on frames between keyframes)
        self._motion = motion
        self._stamps = FileStamps([f for files in (*self._frames.values(), motion or []) for f in files if f is not None])
        h, w = self._check_headers(meta)
        poses = find_poses(self.root, n, (h, w))
        order = tuple(c for c in SPECS if c in self._frames and c not in some)
        self._cache = LRU(cache_size)
        self.info = ShotInfo(
            num_frames=n,
            height=h,
            width=w,
            channels=order,
            fps=float(meta.get("fps", 10.0)),
            caption=str(meta.get("caption", "")),
            object_captions=dict(meta.get("objects", {})),
            poses=poses,
            source=str(self.root),
            extra=dict(meta.get("extra", {})),
            rgb_frames=None if rgb_frames is None else tuple(t for t, f in enumerate(rgb_frames) if f is not None),
            channel_frames=some,
        )
        if some:
            self.info.extra["keyframe_only"] = sorted(some)
        if normalize_irradiance is None:
            normalize_irradiance = not meta.get("irradiance_normalized", False)
        if normalize_irradiance and "irradiance" in self._frames:
            self.info.irradiance_scale = self._measure_exposure()

    def _keyframes(self, folder: Path, meta: dict[str, Any]) -> list[Path | None]:
        """The files of rgb/ (or a light pass's folder: `KEYFRAME_PASSES`) per frame, None where a frame has none (a
        keyframe shot): frame numbers line up with the first other channel's (its first file is frame 0); a frame number
        outside the shot is an error naming the file."""
        numbered = numbered_frames(folder)
        ref = next(iter(self._frames.values()))
        m = FRAME_RE.match(ref[0].name)
        first = int(m["num"]) if m is not None else 0
        n = int(meta.get("num_frames", len(ref)))
        out: list[Path | None] = [None] * n
        for num, path in numbered.items():
            if not 0 <= num - first < n:
                raise ValueError(f"{path}: frame number {num} is outside the shot's frames {first}..{first + n - 1}"
                                 f" (numbered like {ref[0].parent.name}/{ref[0].name})")
            out[num - first] = path
        return out

    def _check_headers(self, meta: dict[str, Any]) -> tuple[int, int]:
        sizes: dict[str, tuple[int, int]] = {}
        for name, files in self._frames.items():
            files = [f for f in files if f is not None]
            spec = read_spec(files[0])
            sizes[name] = (spec.height, spec.width)
        want = (meta["height"], meta["width"]) if "height" in meta and "width" in meta else next(iter(sizes.values()))
        where = "shot.json" if "height" in meta else f"{next(iter(sizes))}/{self._frames[next(iter(sizes))][0].name}"
        for name, s in sizes.items():
            if s != want:
                raise ValueError(f"{next(f for f in self._frames[name] if f is not None)}: size {s[1]}x{s[0]}, but {where} says {want[1]}x{want[0]}")
        return want

    def _measure_exposure(self) -> float:
        lit = self.frames_with("irradiance")
        n = len(lit)
        ts = sorted({lit[int(round(i))] for i in np.linspace(0, n - 1, min(n, EXPOSURE_SAMPLES))})
        total, count = 0.0, 0
        for t in ts:
            s, c = log_luminance_sum(self._decode("irradiance", t, scale=1.0))
            total, count = total + s, count + c
        scale = exposure_scale(total, count)
        log.info("%s: irradiance exposure scale %.4g (measured on %d frames)", self.root, scale, len(ts))
        return scale

    def frame_path(self, name: str, t: int) -> Path:
        """The file holding channel `name` of frame `t`."""
        return (self._motion if name == "motion" else self._frames[name])[t]  # type: ignore[index]

    def _decode(self, name: str, t: int, scale: float | None = None) -> np.ndarray:
        path = self.frame_path(name, t)
        img = self._stamps.read(path, f"frame {t}", reader=read_image)
        if (img.height, img.width) != (self.info.height, self.info.width):
            raise ValueError(f"{path}: size {img.width}x{img.height}, the shot is {self.info.width}x{self.info.height}")
        if name in self._packed:
            a = _packed_component(img, self._packed[name], name, f"{path} (frame {t})")
        else:
            a = to_memory(name, img, where=f"{path} (frame {t})")
        return scale_irradiance(name, a, self.info.irradiance_scale if scale is None else scale)

    def _read(self, name: str, t: int) -> np.ndarray:
        return self._cache.get_or((name, t), lambda: self._decode(name, t))

    def motion(self, t: int) -> np.ndarray | None:
        """(H, W, 2) float32 forward motion of frame t in pixels (NaN where unknown), or None if absent."""
        if self._motion is None or not 0 <= t < len(self._motion):
            return None
        return self._cache.get_or(("motion", t), lambda: self._decode("motion", t))


def _packed_component(img: ImageData, index: int, name: str, where: str) -> np.ndarray:
    """Component `index` (0 = R, 1 = G) of a packed material image, as channel `name` in [0, 1]
    (integer files are taken as values, not sRGB-decoded)."""
    colour = [c for c in img.channel_names if c not in ("A", "a")]
    if len(colour) <= index:
        raise ValueError(f"{where}: a packed material image needs roughness in R and metallic in G; it has {', '.join(img.channel_names)}")
    a = zero_nonfinite(img.stack([("R", "G", "B")[index] if ("R", "G", "B")[index] in img.planes else colour[index]]), where, name)
    return sanitize(name, a, where, check_finite=False)
