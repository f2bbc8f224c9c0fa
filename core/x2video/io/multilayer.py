"""`MultilayerShot`: one multi-layer EXR per frame, with our channel names or Blender's render-pass names.

Our names: ``albedo.R/G/B``, ``normal.X/Y/Z`` (camera space), ``roughness.Y``, ``metallic.Y``,
``irradiance.R/G/B``, ``rgb.R/G/B``, ``ids.id``, ``depth.Z``, ``motion.X/Y``.
Blender's (``<ViewLayer>.<Pass>.<comp>``, short or long pass names):

- albedo: a shader AOV named basecolor / base_color (preferred: Diffuse Color is black on
  metals), else ``DiffCol`` / ``Diffuse Color``;
- normal: ``Normal`` is world space: turned into camera space with the per-frame
  ``cameras.json`` (or nerfstudio ``transforms.json``) beside the frames (docs/SHOT_FORMAT.md), with a warning when it is absent;
- irradiance: ``DiffDir`` + ``DiffInd`` (Blender's diffuse light passes are already divided by
  the diffuse colour: our convention), exposure-normalised once per shot;
- roughness / metallic: shader AOVs with those names (value ``.X`` or colour ``.R``);
- ids: ``IndexOB`` / ``Object Index``; depth: ``Depth`` / ``Z``; rgb: ``Combined`` / ``Image``;
- emission: ``Emit`` + ``Env`` (light the surfaces emit and the world seen directly), in the file's units as
  rgb is (neither is scaled by the irradiance normalisation: rgb - emission is the reflected light);
- diffuse_color: ``DiffCol`` (the colour the diffuse light passes were divided by); glossy_color: ``GlossCol``;
- glossy: ``GlossCol`` x (``GlossDir`` + ``GlossInd``), plus ``TransCol`` x (``TransDir`` + ``TransInd``) and
  ``VolumeDir`` + ``VolumeInd`` where the file has them (`PRODUCTS`), in the file's units as emission. With these,
  rgb = diffuse_color x (DiffDir + DiffInd) + glossy + emission: Cycles' split of Combined (`x2video.base.passes`).

Keyframe shots (the add-on's keyframe export): only some frames carry Combined (the keyframes, listed in
shot.json's ``keyframes``, else found from the frames' headers); the others hold G-buffer passes only.
`ShotInfo.rgb_frames` names the keyframes, and a channel is in the shot's `channels` only when every frame has it; a
pass that some frames lack, such as the keyframes' light passes, is offered on the frames that carry it
(`ShotInfo.channel_frames`, `Shot.has(name, t)`) and named in ``extra["keyframe_only"]``. Irradiance on some frames
only is exposure-normalised once per shot as on every frame, measured on the frames that carry it.
"""
from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from x2video.channels import SPECS
from x2video.io.cache import LRU
from x2video.io.convention import exposure_scale, log_luminance_sum, normalize, sanitize, scale_irradiance, zero_nonfinite
from x2video.io.image import FileStamps, ImageData, read_image, read_spec
from x2video.io.metadata import find_poses, parse_shot_json
from x2video.io.sequence import find_frames
from x2video.shot import Shot, ShotInfo

log = logging.getLogger(__name__)

OURS = {*SPECS, "motion"}
#: Blender pass names (short and long) for each of our channels, in order of preference;
#: a tuple of several passes means their sum.
BLENDER: dict[str, list[tuple[str, ...]]] = {
    "albedo": [("basecolor",), ("base_color",), ("BaseColor",), ("Base Color",), ("DiffCol",), ("Diffuse Color",)],
    "normal": [("Normal",)],
    "irradiance": [("DiffDir", "DiffInd"), ("Diffuse Direct", "Diffuse Indirect"), ("DiffDir",)],
    "roughness": [("Roughness",)],
    "metallic": [("Metallic",), ("metalness",)],
    "ids": [("IndexOB",), ("Object Index",)],
    "depth": [("Depth",), ("Z",)],
    "rgb": [("Combined",), ("Image",)],
    "emission": [("Emit", "Env"), ("Emission", "Environment"), ("Emit",)],
    "diffuse_color": [("DiffCol",), ("Diffuse Color",)],
    "glossy_color": [("GlossCol",), ("Glossy Color",)],
}
#: channels that are sums of products of passes: channel -> terms (colour pass or None, light passes summed), the
#: first term required (short names, then long ones); later terms are added where the file has all their passes
PRODUCTS: dict[str, list[list[tuple[str | None, tuple[str, ...]]]]] = {
    "glossy": [
        [("GlossCol", ("GlossDir", "GlossInd")), ("TransCol", ("TransDir", "TransInd")), (None, ("VolumeDir", "VolumeInd"))],
        [("Glossy Color", ("Glossy Direct", "Glossy Indirect")), ("Transmission Color", ("Transmission Direct", "Transmission Indirect")),
         (None, ("Volume Direct", "Volume Indirect"))],
    ],
}
_COMPS3 = (("R", "G", "B"), ("X", "Y", "Z"), ("r", "g", "b"), ("x", "y", "z"))
_COMPS1 = ("Y", "X", "V", "R", "Z", "id", "r", "x")


@dataclass
class Source:
    """Where one of our channels comes from in the file: full EXR channel names per pass."""

    passes: list[list[str]]  # each pass: component channel names (summed across passes)
    blender: bool
    label: str
    #: per pass, the component names of the colour pass it is multiplied by before the sum (`PRODUCTS`), or None
    factors: list[list[str] | None] | None = None

    def names(self) -> list[str]:
        """Every EXR channel this source reads."""
        return [n for names in [*self.passes, *(f for f in self.factors or () if f)] for n in names]


def group_passes(names: tuple[str, ...]) -> dict[str, dict[str, dict[str, str]]]:
    """layer -> pass -> component -> full channel name ("" layer for two-part names)."""
    out: dict[str, dict[str, dict[str, str]]] = {}
    for full in names:
        parts = full.split(".")
        if len(parts) < 2:
            continue
        comp, pas, layer = parts[-1], parts[-2], ".".join(parts[:-2])
        out.setdefault(layer, {}).setdefault(pas, {})[comp] = full
    return out


def _components(comps: dict[str, str], n: int) -> list[str] | None:
    if n == 1:
        for c in _COMPS1:
            if c in comps:
                return [comps[c]]
        return None
    for cand in _COMPS3[:] if n == 3 else ((("X", "Y"),) + (("R", "G"),)):
        if all(c in comps for c in cand[:n]):
            return [comps[c] for c in cand[:n]]
    return None


def map_channels(names: tuple[str, ...], path: str) -> dict[str, Source]:
    """Which of our channels the file holds, and from which of its channels."""
    layers = group_passes(names)
    if not layers:
        raise ValueError(f"{path}: no layered channels (expected names like 'albedo.R' or 'ViewLayer.DiffCol.R'); has {', '.join(names[:8])}")
    if len(layers) > 1:
        log.warning("%s: several layers %s; using the first that has each pass", path, sorted(layers))
    found: dict[str, Source] = {}
    for layer in sorted(layers):
        passes = layers[layer]
        lower = {p.lower(): p for p in passes}
        for ch in OURS:
            if ch in found:
                continue
            n = 2 if ch == "motion" else SPECS[ch].components
            if ch in passes:  # our own (lower-case) names
                comps = _components(passes[ch], n) if ch != "ids" else _components(passes[ch], 1)
                if comps is None:
                    raise ValueError(f"{path}: layer {ch!r} has components {sorted(passes[ch])}, cannot take {n}")
                found[ch] = Source([comps], False, f"{layer + '.' if layer else ''}{ch}")
                continue
            for combo in BLENDER.get(ch, []):
                keys = [lower.get(p.lower()) for p in combo]
                if ch == "normal" and "Normal" not in passes:
                    continue
                if any(k is None for k in keys):
                    continue
                comps_list = [_components(passes[k], n) for k in keys]  # type: ignore[index]
                if any(c is None for c in comps_list):
                    raise ValueError(f"{path}: pass {layer}.{keys[0]} has components {sorted(passes[keys[0]])}, cannot take {n} for {ch}")  # type: ignore[index]
                found[ch] = Source(comps_list, True, " + ".join(f"{layer}.{k}" for k in keys))  # type: ignore[arg-type]
                break
        for ch, spellings in PRODUCTS.items():
            if ch not in found:
                src = _product(ch, spellings, layer, passes, path)
                if src is not None:
                    found[ch] = src
    return found


def _product(ch: str, spellings: list[list[tuple[str | None, tuple[str, ...]]]], layer: str, passes: dict[str, dict[str, str]],
             path: str) -> Source | None:
    """The `Source` of a `PRODUCTS` channel in one layer (the first spelling whose first term it has), or None."""
    lower = {p.lower(): p for p in passes}
    for terms in spellings:
        parts: list[list[str]] = []
        factors: list[list[str] | None] = []
        labels = []
        for i, (colour, lights) in enumerate(terms):
            keys = [lower.get(p.lower()) for p in ((colour,) if colour else ()) + lights]
            if any(k is None for k in keys):
                if i == 0:
                    break
                continue
            comps = [_components(passes[k], 3) for k in keys]  # type: ignore[index]
            if any(c is None for c in comps):
                raise ValueError(f"{path}: pass {layer}.{keys[0]} has components {sorted(passes[keys[0]])}, cannot take 3 for {ch}")  # type: ignore[index]
            col = comps[0] if colour else None
            for light in comps[1:] if colour else comps:
                parts.append(light)  # type: ignore[arg-type]
                factors.append(col)  # type: ignore[arg-type]
            names = [f"{layer}.{k}" for k in keys]
            labels.append(f"{names[0]} x ({' + '.join(names[1:])})" if colour else " + ".join(names))
        else:
            return Source(parts, True, " + ".join(labels), factors)
    return None


class MultilayerShot(Shot):
    """A lazily read sequence of multi-layer EXR frames (or one file = a one-frame shot).

    normalize_irradiance: None = normalise (XRGB exposure, once per shot) unless the frames say
    they are normalised (our writer's ``x2video:irradiance_normalized`` header, or shot.json).
    """

    def __init__(self, path: str | Path, *, cache_size: int = 24, normalize_irradiance: bool | None = None):
        p = Path(path)
        if p.is_file():
            self._files, folder = [p], p.parent
        else:
            self._files, folder = find_frames(p), p
            self._files = [f for f in self._files]
            bad = [f for f in self._files if f.suffix.lower() != ".exr"]
            if bad:
                raise ValueError(f"{bad[0]}: multi-layer shots are EXR files only")
        self._stamps = FileStamps(self._files)
        spec = read_spec(self._files[0])
        meta: dict[str, Any] = {}
        if (folder / "shot.json").is_file():
            meta = parse_shot_json(folder / "shot.json")
        n = len(self._files)
        if "num_frames" in meta and meta["num_frames"] != n:
            raise ValueError(f"{folder / 'shot.json'}: says {meta['num_frames']} frames, {p} has {n}")
        self._per_frame, rgb_frames, only_keys = self._map_frames(spec, folder, meta.get("keyframes"))
        self._sources = self._per_frame[rgb_frames[0] if rgb_frames else 0]
        self._motion_src = self._sources.get("motion")
        channels = tuple(c for c in SPECS if c in self._sources and c not in only_keys)
        some = {c: tuple(t for t, m in enumerate(self._per_frame) if c in m) for c in SPECS if c in only_keys}
        if not channels:
            raise ValueError(f"{self._files[0]}: no known passes among channels {', '.join(tuple(spec.channelnames)[:12])}")
        poses = find_poses(folder, n, (spec.height, spec.width))
        src_n = self._sources.get("normal")
        self._world_normals = bool(src_n and src_n.blender)
        if self._world_normals and poses is None:
            warnings.warn(
                f"{folder}: Blender Normal pass is in world space and there is no cameras.json or transforms.json beside the frames;"
                " normals are used as they are (world space)",
                RuntimeWarning,
                stacklevel=2,
            )
        self._cache = LRU(max(1, cache_size // max(1, len(channels))))
        extra = {**dict(meta.get("extra", {})), "passes": {k: s.label for k, s in self._sources.items() if k != "motion"}}
        if only_keys:
            extra["keyframe_only"] = sorted(only_keys)
        self.info = ShotInfo(
            num_frames=n,
            height=spec.height,
            width=spec.width,
            channels=channels,
            fps=float(meta.get("fps", 10.0)),
            caption=str(meta.get("caption", "")),
            object_captions=dict(meta.get("objects", {})),
            poses=poses,
            source=str(p),
            extra=extra,
            rgb_frames=None if rgb_frames is None or len(rgb_frames) == n else tuple(rgb_frames),
            channel_frames=some,
        )
        already = bool(spec.getattribute("x2video:irradiance_normalized") or meta.get("irradiance_normalized", False))
        if normalize_irradiance is None:
            normalize_irradiance = not already
        lit = self.frames_with("irradiance")
        if normalize_irradiance and lit:
            ts = sorted({lit[int(round(i))] for i in np.linspace(0, len(lit) - 1, min(len(lit), 16))})
            total, count = 0.0, 0
            for t in ts:
                s, c = log_luminance_sum(self._frame(t, scale=1.0, only=("irradiance",))["irradiance"])
                total, count = total + s, count + c
            self.info.irradiance_scale = exposure_scale(total, count)
            self._cache.clear()

    def _map_frames(self, spec: Any, folder: Path, listed: list[int] | None) -> tuple[list[dict[str, Source]], list[int] | None, set[str]]:
        """Each frame's sources (read from its header: a keyframe shot's frames hold different passes), the frames that
        carry rgb (shot.json's `listed` keyframes, else every frame with Combined; None without rgb) and the channels
        some frames lack (left out of the shot; rgb is the keyframes' own)."""
        maps: dict[tuple[str, ...], dict[str, Source]] = {}
        per_frame = []
        for t, f in enumerate(self._files):
            names = tuple((spec if t == 0 else read_spec(f)).channelnames)
            if names not in maps:
                maps[names] = map_channels(names, str(f))
            per_frame.append(maps[names])
        with_rgb = [t for t, m in enumerate(per_frame) if "rgb" in m]
        if listed is not None:
            where = folder / "shot.json"
            bad = [t for t in listed if not 0 <= t < len(self._files)]
            if bad:
                raise ValueError(f"{where}: keyframes {bad} lie outside the shot's {len(self._files)} frames")
            lacking = [t for t in listed if "rgb" not in per_frame[t]]
            if lacking:
                raise ValueError(f"{self._files[lacking[0]]}: shot.json lists frame {lacking[0]} as a keyframe, but it carries no Combined pass")
            with_rgb = list(listed)
        present = [set(m) - {"rgb", "motion"} for m in maps.values()]
        only_keys = set.union(*present) - set.intersection(*present)
        return per_frame, with_rgb or None, only_keys

    def _frame(self, t: int, scale: float | None = None, only: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
        """Our channels of frame t (those in `only`, default all), reading only the EXR channels they come from
        (a Blender frame holds every light pass: `x2video.io.image.read_image`)."""
        path = self._files[t]
        want = (*self.info.channels, *self.info.channel_frames) if only is None else only
        sources = {ch: src for ch, src in self._per_frame[t].items() if ch in want and (ch != "rgb" or self.has_rgb(t))}
        img = self._stamps.read(path, f"frame {t}", channels=[n for src in sources.values() for n in src.names()], reader=read_image)
        if (img.height, img.width) != (self.info.height, self.info.width):
            raise ValueError(f"{path}: size {img.width}x{img.height}, frame 0 is {self.info.width}x{self.info.height}")
        where = f"{path} (frame {t})"
        out: dict[str, np.ndarray] = {}
        for ch, src in sources.items():
            out[ch] = self._convert(ch, src, img, where, t, self.info.irradiance_scale if scale is None else scale)
        return out

    def _convert(self, ch: str, src: Source, img: ImageData, where: str, t: int, scale: float) -> np.ndarray:
        try:
            parts = [img.stack(names, np.float64 if ch == "ids" else np.float32) for names in src.passes]
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
        if ch == "ids":
            raw = img.planes[src.passes[0][0]]
            if raw.dtype.kind in "ui":
                return raw.astype(np.int32)[..., None]
            v = np.nan_to_num(parts[0], nan=0, posinf=0, neginf=0)
            return np.clip(np.rint(v), 0, 2**31 - 1).astype(np.int32)
        if src.factors is not None:
            parts = [p if f is None else p * img.stack(f, np.float32) for p, f in zip(parts, src.factors)]
        a = zero_nonfinite(np.sum(parts, axis=0).astype(np.float32), where, ch)
        if ch == "normal" and self._world_normals and self.info.poses is not None:
            r = np.asarray(self.info.poses[t].cam_to_world, np.float32)[:3, :3]
            a = normalize(a) @ r  # (H, W, 3): n_cam = R^T n_world, row-vector form
        return sanitize(ch, scale_irradiance(ch, a, scale), where, check_finite=False)

    def _read(self, name: str, t: int) -> np.ndarray:
        return self._cache.get_or(t, lambda: self._frame(t))[name]

    def motion(self, t: int) -> np.ndarray | None:
        """(H, W, 2) forward motion of frame t (our ``motion.X/Y`` layer), or None."""
        if self._motion_src is None:
            return None
        img = self._stamps.read(self._files[t], f"frame {t}", channels=self._motion_src.passes[0], reader=read_image)
        return img.stack(self._motion_src.passes[0])
