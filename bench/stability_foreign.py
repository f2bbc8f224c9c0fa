"""The stability bench's foreign inputs (issue 49): our own shots rewritten the way other tools write them, then read
back through the product's own loaders, as a user's files would be.

A case is a `Foreign` recipe: a layout ('xrgb': the XRGB release's flat `<name>-<channel>.png` sets, 8-bit, albedo and
irradiance gamma-2.2 as that release reads them; 'video': V-RGBX's one H.264 video per channel, 8-bit sRGB), the
irradiance's scale (another renderer's units: our exposure-normalised irradiance times `irradiance_gain` before it is
quantised, so it clips where it passes 1), its encoding ('gamma2.2' or 'srgb': the curve the file was written with;
the XRGB loader always decodes gamma 2.2), the frame size (resampled: 1024x1024, 1920x1080) and an emissive fixture (a
pendant lamp under the ceiling: a disc whose irradiance and picture are far brighter than the room, which lights the
ceiling around it; added to the irradiance and to the picture as albedo x its light, so the formula stays exact off
the disc). The picture (`-ref.png`, `_RGB.mp4`) is the source's truth through the same 8-bit sRGB encoding.

Such a truth is in the foreign tool's units, not ours, so the family scores every method after one fitted exposure
per frame (`best_exposure`), as the issue's kitchen was scored.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np

from x2video.channels import linear_to_srgb
from x2video.shot import Shot


@dataclasses.dataclass(frozen=True)
class Foreign:
    """One way another tool writes a shot (see the module docstring)."""

    layout: str = "xrgb"
    irradiance_gain: float = 1.0
    irradiance_encoding: str = "gamma2.2"
    size: tuple[int, int] | None = None  # (W, H); None: the source's
    emitter: bool = False


#: the family's cases (name -> recipe); `QUICK` runs a few
CASES: dict[str, Foreign] = {
    "xrgb_png": Foreign(),
    "xrgb_irr_srgb": Foreign(irradiance_encoding="srgb"),
    "xrgb_irr_x0.1": Foreign(irradiance_gain=0.1),
    "xrgb_irr_x0.01": Foreign(irradiance_gain=0.01),  # the scale tier 1 misreads (bench.plausible_bound's fooled cases)
    "xrgb_irr_x4": Foreign(irradiance_gain=4.0),
    "xrgb_irr_srgb_x3": Foreign(irradiance_gain=3.0, irradiance_encoding="srgb"),
    "xrgb_emitter": Foreign(emitter=True),
    "xrgb_1024": Foreign(size=(1024, 1024)),
    "xrgb_1920x1080": Foreign(size=(1920, 1080)),
    "kitchen_like_1024": Foreign(size=(1024, 1024), emitter=True, irradiance_gain=3.0, irradiance_encoding="srgb"),
    "video": Foreign(layout="video"),
    "video_emitter": Foreign(layout="video", emitter=True),
}
QUICK = ("xrgb_png", "xrgb_irr_x0.01", "xrgb_emitter", "kitchen_like_1024", "video")

#: the fixture: centre (x, y) and radius as fractions of the frame's width/height; its disc's light in units of the frame's
#: mean irradiance; the light it throws around, at its edge, in the same units
LAMP_CENTRE, LAMP_RADIUS, LAMP_LEVEL, LAMP_GLOW = (0.5, 0.12), 0.05, 40.0, 3.0


def lamp(size: tuple[int, int], level: float) -> tuple[np.ndarray, np.ndarray]:
    """((H, W) bool disc of the fixture, (H, W) light it adds around it) for a frame of `size` (H, W) whose mean irradiance
    is `level`: the disc at LAMP_LEVEL x level, falling off as 1/(1 + (d/r)^2) around it from LAMP_GLOW x level."""
    h, w = size
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    r = LAMP_RADIUS * min(h, w)
    d = np.hypot(x - LAMP_CENTRE[0] * w, y - LAMP_CENTRE[1] * h)
    disc = d <= r
    glow = LAMP_GLOW * level / (1.0 + (np.maximum(d - r, 0) / r) ** 2)
    return disc, np.where(disc, LAMP_LEVEL * level, glow).astype(np.float32)


def foreign_channels(src: Shot, t: int, case: Foreign, rgb: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Frame t of `src` as the foreign tool holds it before writing, linear and in our channel names: resized, the
    fixture added, irradiance and picture in the foreign scale (irradiance x `irradiance_gain`, the picture divided by
    the source's exposure normalisation and times the same gain, so formula and truth share the foreign units).
    `rgb`: the picture to take instead of the source's (its truth apart, for scoring)."""
    from bench.stability_shots import resize_channel

    size = src.size if case.size is None else (case.size[1], case.size[0])
    ch = {n: resize_channel(n, np.nan_to_num(src.channel(n, t) if n != "rgb" or rgb is None else rgb), size)
          for n in ("albedo", "normal", "roughness", "metallic", "irradiance", "rgb")}
    s = float(src.info.irradiance_scale)
    irr, rgb = ch["irradiance"] / s, ch["rgb"]  # both in the source renderer's units
    if case.emitter:
        disc, light = lamp(size, float(irr.mean()))
        lit = irr.max(-1) > 1e-3 * float(irr.mean())  # diffuse surfaces: not the sky, not clear glass (a diffuse pass is 0 there)
        light = np.where(lit | disc, light, 0)
        ch["normal"][disc] = (0.0, 0.0, 1.0)  # a surface facing the camera, never a window
        al = ch["albedo"]
        al[disc] = (0.9, 0.85, 0.7)  # a warm shade
        irr = irr + light[..., None]
        rgb = np.where(disc[..., None], light[..., None], rgb + al * light[..., None])
    ch["irradiance"] = irr * s * case.irradiance_gain
    ch["rgb"] = rgb * s * case.irradiance_gain
    return ch


def _u8(a: np.ndarray) -> np.ndarray:
    return np.round(np.clip(a, 0, 1) * 255).astype(np.uint8)


def encode(name: str, a: np.ndarray, case: Foreign) -> np.ndarray:
    """(H, W, 3) uint8 of channel `name` as the foreign tool writes it (the XRGB release's conventions; V-RGBX's sRGB)."""
    a = np.asarray(a, np.float32)
    if a.shape[-1] == 1:
        a = np.repeat(a, 3, -1)
    if name == "normal":
        return _u8(a * 0.5 + 0.5)
    if name in ("roughness", "metallic"):
        return _u8(a)
    if name == "rgb" or case.layout == "video" or (name == "irradiance" and case.irradiance_encoding == "srgb"):
        return _u8(linear_to_srgb(a))
    return _u8(np.power(np.clip(a, 0, 1), 1 / 2.2))  # albedo (and irradiance) as the XRGB release decodes them: v ** 2.2


def write_foreign(src: Shot, frames: int, case: Foreign, folder: Path) -> Path:
    """Write `frames` frames of `src` into `folder` the way `case` says; the path to load (a folder)."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    chans = [foreign_channels(src, t, case) for t in range(frames)]
    if case.layout == "xrgb":
        for t, ch in enumerate(chans):
            for n, a in ch.items():
                cv2.imwrite(str(folder / f"shot_{t:04d}-{'ref' if n == 'rgb' else n}.png"), encode(n, a, case)[..., ::-1])
        return folder
    if case.layout != "video":
        raise ValueError(f"unknown foreign layout {case.layout!r} (xrgb, video)")
    return _write_videos(chans, case, folder)


def _write_videos(chans: list[dict[str, np.ndarray]], case: Foreign, folder: Path, fps: int = 12) -> Path:
    """V-RGBX's layout: shot_Albedo.mp4, shot_Normal.mp4, shot_Material.mp4 (R roughness, G metallic), shot_Irradiance.mp4,
    shot_RGB.mp4; H.264 yuv420p at crf 12, as most tools write them."""
    import av

    h, w = chans[0]["albedo"].shape[:2]
    frames = {"Albedo": [encode("albedo", c["albedo"], case) for c in chans],
              "Normal": [encode("normal", c["normal"], case) for c in chans],
              "Material": [np.concatenate([encode("roughness", c["roughness"], case)[..., :1], encode("metallic", c["metallic"], case)[..., :1],
                                           np.zeros((h, w, 1), np.uint8)], -1) for c in chans],
              "Irradiance": [encode("irradiance", c["irradiance"], case) for c in chans],
              "RGB": [encode("rgb", c["rgb"], case) for c in chans]}
    for word, fs in frames.items():
        with av.open(str(folder / f"shot_{word}.mp4"), mode="w") as c:
            s = c.add_stream("libx264", rate=fps)
            s.width, s.height, s.pix_fmt, s.options = w, h, "yuv420p", {"crf": "12"}
            for f in fs:
                for pkt in s.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")):
                    c.mux(pkt)
            for pkt in s.encode():
                c.mux(pkt)
    return folder


def foreign_shot(src: Shot, frames: int, case: Foreign, root: Path) -> Shot:
    """`src`'s first `frames` frames written as `case` says under `root` (once: a folder per source and recipe, reused
    by every method of the case) and loaded back with `x2video.io.load_shot`, as a user's files would be."""
    from x2video.io import load_shot

    key = hashlib.sha1(json.dumps([str(src.info.source), frames, dataclasses.asdict(case)]).encode()).hexdigest()[:12]
    folder = root / key
    if not (folder / "done").is_file():
        write_foreign(src, frames, case, folder)
        (folder / "done").write_text("")
    return load_shot(folder)


def best_exposure(frame: np.ndarray, truth: np.ndarray, tonemap) -> float:
    """The one factor s on linear `frame` whose `tonemap(s * frame)` is closest (MSE) to `tonemap(truth)`: a coarse
    search over 1/64 .. 64 in log steps, then a finer one around the best (the scores are not convex in s: clipping)."""
    f, g = np.asarray(frame, np.float32)[::2, ::2], tonemap(np.asarray(truth, np.float32))[::2, ::2]  # every other pixel: enough for one number

    def err(s: float) -> float:
        return float(((tonemap(s * f) - g) ** 2).mean())

    grid = np.exp(np.linspace(np.log(1 / 64), np.log(64), 49))
    best = float(grid[int(np.argmin([err(s) for s in grid]))])
    fine = best * np.exp(np.linspace(-0.1, 0.1, 21))
    return float(fine[int(np.argmin([err(s) for s in fine]))])
