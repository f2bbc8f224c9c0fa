"""`XRGBShot`: the XRGB (RGB<->X) release's example format, `<name>-albedo.png` ... `<name>-irradiance.png`.

Conversions are that release's, from zheng95z/rgbx (commit 168f2d7) x2rgb/gradio_demo_x2rgb.py
and x2rgb/load_image.py:
- albedo: PNG/JPG ``v ** 2.2`` (a plain gamma, not the sRGB curve); EXR clamped to [0, 1];
- normal: PNG/JPG ``2v - 1`` then normalised (eps 1e-6); EXR normalised;
- roughness, metallic: clamped to [0, 1] (we keep one component of the release's three);
- irradiance: PNG/JPG ``v ** 2.2`` clamped; EXR exposure-normalised (0.18 / geometric-mean
  luminance, see `x2video.io.convention.exposure_scale`) then clamped to [0, 1].
One difference, on purpose: for a sequence (several numbered sets, e.g. ``kitchen_0001-albedo.png``)
the irradiance exposure is measured once over the whole shot, not per frame (per-frame
auto-exposure flickers). ``<name>-ref.png`` (optional) loads as the `rgb` channel (sRGB-decoded).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from x2video.channels import INTRINSIC, SPECS
from x2video.io.cache import LRU
from x2video.io.convention import exposure_scale, log_luminance_sum, scale_irradiance, to_memory
from x2video.io.image import IMAGE_EXTENSIONS, FileStamps, read_image, read_spec
from x2video.shot import Shot, ShotInfo

SUFFIXES = {**{c: c for c in INTRINSIC}, "ref": "rgb"}
SET_RE = re.compile(r"^(?P<name>.+)-(?P<kind>albedo|normal|roughness|metallic|irradiance|ref)(?P<ext>\.[A-Za-z]+)$")


def find_xrgb_sets(folder: Path, strict: bool = True) -> dict[str, dict[str, Path]]:
    """name -> our channel -> file, for every `<name>-<channel>.<ext>` set in `folder`."""
    sets: dict[str, dict[str, Path]] = {}
    for p in sorted(folder.iterdir()):
        if not p.is_file() or p.name.startswith(".") or p.suffix.lower() not in IMAGE_EXTENSIONS:
            continue
        m = SET_RE.match(p.name)
        if m is None:
            continue
        ch = SUFFIXES[m["kind"]]
        have = sets.setdefault(m["name"], {})
        if ch in have:
            if strict:
                raise ValueError(f"{p}: set {m['name']!r} has two {m['kind']} files ({have[ch].name} and {p.name})")
            continue
        have[ch] = p
    return sets


def _order(names: list[str], folder: Path) -> list[str]:
    if len(names) == 1:
        return names
    nums: dict[int, str] = {}
    for n in names:
        m = re.search(r"(\d+)$", n)
        if m is None:
            raise ValueError(f"{folder}: several XRGB sets ({', '.join(names[:4])}) and {n!r} has no frame number; give one set's file")
        k = int(m.group(1))
        if k in nums:
            raise ValueError(f"{folder}: sets {nums[k]!r} and {n!r} have the same frame number {k}")
        nums[k] = n
    keys = sorted(nums)
    for a, b in zip(keys, keys[1:]):
        if b != a + 1:
            raise ValueError(f"{folder}: gap in XRGB set numbering: {nums[a]!r} is followed by {nums[b]!r}")
    return [nums[k] for k in keys]


class XRGBShot(Shot):
    """One XRGB set (a one-frame shot) or a numbered sequence of sets, read lazily."""

    def __init__(self, path: str | Path, *, cache_size: int = 24, normalize_irradiance: bool | None = None):
        p = Path(path)
        if p.is_file():
            m = SET_RE.match(p.name)
            if m is None:
                raise ValueError(f"{p}: not an XRGB file (expected <name>-albedo.png, -normal, -roughness, -metallic, -irradiance, -ref)")
            folder, names = p.parent, [m["name"]]
            sets = {m["name"]: find_xrgb_sets(folder)[m["name"]]}
        else:
            folder = p
            sets = find_xrgb_sets(folder)
            if not sets:
                raise ValueError(f"{folder}: no XRGB files (<name>-albedo.png ...)")
            names = _order(sorted(sets), folder)
        chans = [c for c in SPECS if c in sets[names[0]]]
        for n in names:
            if [c for c in SPECS if c in sets[n]] != chans:
                raise ValueError(
                    f"{folder}: set {n!r} has channels {sorted(sets[n])}, set {names[0]!r} has {sorted(chans)}; every frame needs the same"
                )
        self._files = [sets[n] for n in names]
        self._stamps = FileStamps([f for files in self._files for f in files.values()])
        size = None
        for c in chans:
            spec = read_spec(self._files[0][c])
            if size is None:
                size = (spec.height, spec.width)
            elif (spec.height, spec.width) != size:
                raise ValueError(f"{self._files[0][c]}: size {spec.width}x{spec.height}, {chans[0]} is {size[1]}x{size[0]}")
        assert size is not None
        self._cache = LRU(cache_size)
        self.info = ShotInfo(num_frames=len(names), height=size[0], width=size[1], channels=tuple(chans), source=str(p), extra={"xrgb_names": names})
        irr_exr = "irradiance" in chans and self._files[0]["irradiance"].suffix.lower() == ".exr"
        if (normalize_irradiance is None and irr_exr) or normalize_irradiance:
            total, count = 0.0, 0
            n = len(names)
            for t in sorted({int(round(i)) for i in np.linspace(0, n - 1, min(n, 16))}):
                s, c = log_luminance_sum(self._decode("irradiance", t, scale=1.0))
                total, count = total + s, count + c
            self.info.irradiance_scale = exposure_scale(total, count)

    def _decode(self, name: str, t: int, scale: float | None = None) -> np.ndarray:
        path = self._files[t][name]
        img = self._stamps.read(path, f"frame {t}", reader=read_image)
        if (img.height, img.width) != (self.info.height, self.info.width):
            raise ValueError(f"{path}: size {img.width}x{img.height}, the shot is {self.info.width}x{self.info.height}")
        a = to_memory(name, img, ldr_decode="srgb" if name == "rgb" else "gamma2.2", where=f"{path} (frame {t})")
        a = scale_irradiance(name, a, self.info.irradiance_scale if scale is None else scale)
        if name == "irradiance" and scale is None:
            a = np.clip(a, 0.0, 1.0)  # the release clamps irradiance to [0, 1]
        return a

    def _read(self, name: str, t: int) -> np.ndarray:
        return self._cache.get_or((name, t), lambda: self._decode(name, t))
