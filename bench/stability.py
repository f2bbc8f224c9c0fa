"""Stability where methods fail: every tier on the inputs that break renderers, with what happens (issue 30 item 3).

Each cell renders one case with one method and records PSNR (display images, `x2video.channels.tonemap`, in
the shot's own units: frames divided by `shot.info.irradiance_scale`), TC (DIS flow on the ground truth),
seconds, peak RSS (the process's high-water mark, reset before the cell through /proc/self/clear_refs),
the share of non-finite output values and whether it crashed (the exception's message). Methods:

    formula    tier 0, albedo x irradiance (RenderSettings.quality 'formula')
    residual   tier 1 forced (quality 'residual'): one pass of the tier-1 net over the formula
    auto       what the product picks (tier 1 where nothing must be generated and the net's record trusts it,
               else the formula; the sampler where something must be generated), preset fast
    diffusion  the video diffusion sampler, preset fast (LCM-2 with the shipped weights)

Families (the grid; `--quick` runs a few cells of each at small sizes and short shots):

    channels  the 32 subsets of the five channels kept (the rest dropped via Edits.dropped)
    masks     0-16 masks from the ids channel (rectangles without one), MaskOut A|M|R in each, with and
              without local prompts (the object's caption); PSNR inside / outside the masks
    length    1 .. 1,000 frames of a lazily looped shot (ping-pong over the source's frames, never in
              memory): mean CIE76 Lab dE to the ground truth along the shot (drift) and memory
    size      8x8 .. 1920x1080, sizes not divisible by 8 (the source resized on the fly)
    noise     the irradiance as Cycles sampled it (NoisyDiffDir + NoisyDiffInd, before denoising), and
              Poisson-like noise emulating 1 .. 128 samples per pixel
    hostile   NaN, +-Inf and 1e6 irradiance in a patch, negative roughness, zero normals, albedo 0 or 1
    limits    the paper's limitation cases per pixel class: window (normal == 0), metal (metallic > 0.5),
              mirror (metallic > 0.5 and roughness < 0.05), other

Source data: `--data`, a folder of path-traced shots with rgb ground truth (Cycles multi-layer EXRs, e.g.
DATA/test); without it a small synthetic shot (numpy, no renderer) stands in and the results say so.
The diffusion tier is skipped (recorded as skipped, with why) above `--diffusion-max-pixels` and
`--diffusion-max-frames`: on a 2-core CPU a 1920x1080 or 1,000-frame diffusion render takes hours.

    python -m bench.stability [--quick] [--data DATA/test] [--families channels,masks,...] [--methods formula,residual,auto,diffusion]

Writes bench/results/stability/stability[_quick].json and docs/STABILITY.md with its plots (docs/stability/).
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import re
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from x2video.channels import INTRINSIC, tonemap
from x2video.shot import Shot, ShotInfo

FAMILIES = ("channels", "masks", "length", "noise", "hostile", "limits", "size")  # size last: its big frames raise the RSS floor
METHODS = ("formula", "residual", "auto", "diffusion")
#: frames whose display images are kept for TC (the rest of a long shot is scored frame by frame only)
TC_FRAMES = 65
#: a method counts as "far below the formula" this many dB under it
FAR_BELOW_DB = 3.0
DOCS = Path(__file__).resolve().parents[1] / "docs"


# --------------------------------------------------------------------------------------------- memory
def _status_kb(key: str) -> int:
    try:
        m = re.search(rf"^{key}:\s+(\d+) kB", Path("/proc/self/status").read_text(), re.M)
        return int(m.group(1)) if m else 0
    except OSError:
        return 0


def reset_peak_rss() -> bool:
    """Reset the process's peak RSS (VmHWM) to its current RSS (Linux >= 4.0); False where that is not possible."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def peak_rss_mb() -> float:
    """The process's peak RSS in MiB since the last `reset_peak_rss` (VmHWM; ru_maxrss where /proc is missing)."""
    kb = _status_kb("VmHWM")
    if not kb:
        import resource

        kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kb / 1024.0


def release_memory() -> None:
    """Collect garbage and hand freed heap back to the OS (glibc malloc_trim), so the next cell starts low."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def rss_mb() -> float:
    return _status_kb("VmRSS") / 1024.0


# --------------------------------------------------------------------------------------------- shots
class SyntheticShot(Shot):
    """A small analytic stand-in when no path-traced data is given: a sliding checker of albedos, a tilted
    normal field, a window (normal 0) and a metal strip, irradiance from a moving light; rgb = albedo x
    irradiance (plus a glossy term on the metal), in normalised units (irradiance_scale 1)."""

    def __init__(self, num_frames: int = 8, size: tuple[int, int] = (56, 80)):
        h, w = size
        self.info = ShotInfo(num_frames=num_frames, height=h, width=w, channels=(*INTRINSIC, "rgb", "ids"), caption="a synthetic room",
                             object_captions={1: "a red wall", 2: "a blue floor", 3: "a metal strip"}, source="synthetic")

    def _read(self, name: str, t: int) -> np.ndarray:
        h, w = self.size
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        x = x + 1.5 * t
        ids = (1 + ((x // 12 + y // 12) % 2)).astype(np.int32)
        window = (x % 60 < 10) & (y < h * 0.3)
        metal = (y > h * 0.7) & (x % 40 < 15)
        ids[metal] = 3
        ids[window] = 0
        if name == "ids":
            return ids[..., None]
        if name == "albedo":
            a = np.where(ids[..., None] == 1, [0.7, 0.2, 0.15], np.where(ids[..., None] == 2, [0.15, 0.25, 0.6], [0.9, 0.9, 0.9]))
            return np.where(window[..., None], 0.0, a).astype(np.float32)
        if name == "normal":
            n = np.stack([np.sin(x / w), np.zeros_like(y), np.cos(x / w)], -1)
            return np.where(window[..., None], 0.0, n).astype(np.float32)
        if name == "roughness":
            return np.where(metal, 0.03, 0.6).astype(np.float32)[..., None]
        if name == "metallic":
            return metal.astype(np.float32)[..., None]
        irr = (0.6 + 0.5 * np.exp(-((x - w / 2 - 3 * t) ** 2 + (y - h / 3) ** 2) / (0.1 * w * w)))[..., None] * np.array([1.0, 0.95, 0.85])
        irr = np.where(window[..., None], 0.0, irr).astype(np.float32)
        if name == "irradiance":
            return irr
        if name == "rgb":
            rgb = self._read("albedo", t) * irr + metal[..., None] * 0.3 * irr
            return np.where(window[..., None], 1.5, rgb).astype(np.float32)
        raise KeyError(name)


class ViewShot(Shot):
    """A lazy view of a source shot: frame t is source frame `src_index(t)` (ping-pong through the source, so
    any length has continuous motion), resized to `size`, then passed through `transform(name, array, t)`.
    Nothing is held: each read goes to the source (whose loader keeps a small LRU cache)."""

    def __init__(self, src: Shot, num_frames: int | None = None, size: tuple[int, int] | None = None,
                 transform: Callable[[str, np.ndarray, int], np.ndarray] | None = None, start: int = 0):
        self.src, self.transform, self.start = src, transform, start
        h, w = size or src.size
        self.info = dataclasses.replace(src.info, num_frames=int(num_frames or src.num_frames - start), height=h, width=w, poses=None)

    def src_index(self, t: int) -> int:
        n = self.src.num_frames - self.start
        if n <= 1:
            return self.start
        k = t % (2 * (n - 1))
        return self.start + (k if k < n else 2 * (n - 1) - k)

    def _read(self, name: str, t: int) -> np.ndarray:
        import cv2

        a = self.src.channel(name, self.src_index(t))
        if a.shape[:2] != self.size:
            h, w = self.size
            if name == "ids":
                r = cv2.resize(a[..., 0].astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
            else:
                interp = cv2.INTER_AREA if h < a.shape[0] else cv2.INTER_LINEAR
                r = cv2.resize(np.ascontiguousarray(a, np.float32), (w, h), interpolation=interp)
            a = (r if r.ndim == 3 else r[..., None]).astype(a.dtype)
        if self.transform is not None:
            a = self.transform(name, a, t)
        return a


# --------------------------------------------------------------------------------------------- scoring
CLASS_SETS = {
    "limits": ("other", "window", "metal", "mirror"),
    "masks": ("outside", "inside"),
}


def limitation_classes(fr: dict[str, np.ndarray]) -> np.ndarray:
    """(H, W) index into CLASS_SETS['limits']: normal == 0 -> window; metallic > 0.5 -> metal; and
    roughness < 0.05 -> mirror."""
    nrm = np.linalg.norm(np.nan_to_num(fr["normal"]), axis=-1)
    met, rough = fr["metallic"][..., 0], fr["roughness"][..., 0]
    cls = np.zeros(nrm.shape, np.int8)
    cls[met > 0.5] = 2
    cls[(met > 0.5) & (rough < 0.05)] = 3
    cls[nrm < 1e-3] = 1
    return cls


def _psnr(mse: float) -> float:
    return 100.0 if mse <= 1e-10 else 10.0 * math.log10(1.0 / mse)


class Scorer:
    """Scores frames as they arrive (a render's FramesReady events; a later delivery of a frame replaces the
    earlier), against the ground truth read lazily from `gt_shot`; keeps display images only for TC's first
    TC_FRAMES frames, so a 1,000-frame shot is never in memory. Its own time is kept apart (`seconds`)."""

    def __init__(self, gt_shot: Shot, scale: float, classes: Callable[[int], np.ndarray] | None = None, class_names: tuple[str, ...] = (),
                 delta_e: bool = False):
        self.gt_shot, self.scale, self.classes, self.class_names, self.delta_e = gt_shot, scale, classes, class_names, delta_e
        self.per_frame: dict[int, dict] = {}
        self.keep: dict[int, np.ndarray] = {}
        self.seconds = 0.0

    def on_event(self, e: Any) -> None:
        from x2video.sampling.events import FramesReady

        if isinstance(e, FramesReady):
            t0 = time.perf_counter()
            for t, f in e.frames.items():
                self.add(t, f)
            self.seconds += time.perf_counter() - t0

    def add(self, t: int, frame: np.ndarray) -> None:
        frame = np.asarray(frame, np.float32)
        bad = int((~np.isfinite(frame)).sum())
        disp = tonemap(np.nan_to_num(frame, nan=0.0, posinf=1e6, neginf=0.0) / self.scale)
        gt = tonemap(np.nan_to_num(self.gt_shot.channel("rgb", t)))
        if disp.shape != gt.shape:
            raise ValueError(f"frame {t}: output {disp.shape[1]}x{disp.shape[0]}, the shot is {gt.shape[1]}x{gt.shape[0]}")
        sq = ((disp.astype(np.float64) - gt) ** 2).mean(-1)  # (H, W)
        rec = {"mse": float(sq.mean()), "bad": bad, "n": frame.size, "mean": float(disp.mean())}
        if self.classes is not None:
            c = self.classes(t)
            rec["sse"] = [float(sq[c == k].sum()) for k in range(len(self.class_names))]
            rec["npx"] = [int((c == k).sum()) for k in range(len(self.class_names))]
        if self.delta_e:
            from skimage.color import rgb2lab

            rec["de"] = float(np.linalg.norm(rgb2lab(disp) - rgb2lab(gt), axis=-1).mean())
        self.per_frame[t] = rec
        if t < TC_FRAMES:
            self.keep[t] = disp.astype(np.float16)

    def result(self, num_frames: int) -> dict:
        t0 = time.perf_counter()
        got = sorted(self.per_frame)
        out: dict[str, Any] = {"frames_out": len(got), "frames_missing": num_frames - len(got)}
        if not got:
            return out
        recs = [self.per_frame[t] for t in got]
        out["psnr"] = float(np.mean([_psnr(r["mse"]) for r in recs]))
        out["mean_display"] = float(np.mean([r["mean"] for r in recs]))
        out["nonfinite_frac"] = float(sum(r["bad"] for r in recs) / max(sum(r["n"] for r in recs), 1))
        if self.classes is not None:
            sse, npx = np.sum([r["sse"] for r in recs], 0), np.sum([r["npx"] for r in recs], 0)
            out["psnr_by_class"] = {c: (_psnr(s / n) if n else None) for c, s, n in zip(self.class_names, sse, npx)}
            out["pixel_share"] = {c: float(n / max(npx.sum(), 1)) for c, n in zip(self.class_names, npx)}
        if self.delta_e:
            de = np.array([r["de"] for r in recs])
            k = max(1, len(de) // 10)
            out["delta_e"] = float(de.mean())
            out["delta_e_first"] = float(de[:k].mean())
            out["delta_e_last"] = float(de[-k:].mean())
            idx = np.linspace(0, len(de) - 1, min(len(de), 100)).round().astype(int)
            out["delta_e_series"] = [[int(got[i]), round(float(de[i]), 3)] for i in idx]
        kept = [t for t in range(min(num_frames, TC_FRAMES)) if t in self.keep]
        if len(kept) >= 2 and kept == list(range(len(kept))):
            from x2video.metrics.temporal import temporal_consistency

            gts = [tonemap(np.nan_to_num(self.gt_shot.channel("rgb", t))) for t in kept]
            try:
                out["tc"] = temporal_consistency([self.keep[t].astype(np.float32) for t in kept], gts).tc
                out["tc_frames"] = len(kept)
            except Exception as exc:  # noqa: BLE001 - no pixel with valid flow, or a frame too small for DIS (< 12 px)
                out["tc_error"] = f"{type(exc).__name__}: {exc}".strip()[:200]
        self.seconds += time.perf_counter() - t0
        return out


# --------------------------------------------------------------------------------------------- cases
@dataclass
class Context:
    """What cells share: the source shots, the model (loaded on first use) and the limits."""

    sources: list[Shot]
    weights: str | None = None
    residual: str | None = None
    diffusion_max_pixels: int = 640 * 360
    diffusion_max_frames: int = 65
    threads: int = 2
    untrained: bool = False
    _model: Any = None
    model_info: dict = field(default_factory=dict)

    def model(self):
        if self._model is None:
            import torch

            from x2video.weights import load_model

            try:
                m = load_model(self.weights, device="cpu", untrained=self.untrained)
                self.model_info["weights"] = "untrained tiny (test)" if self.untrained else ("shipped" if self.weights is None else "given folder")
            except Exception as exc:  # the shipped weights fail to load: the untrained fallback, said loudly
                self.model_info["weights_error"] = f"{type(exc).__name__}: {exc}"
                self.model_info["weights"] = "untrained tiny (fallback: the weights failed to load)"
                m = load_model(None, device="cpu", untrained=True)
            if self.residual:
                from x2video.model.residual import engine, load

                m.residual_net = engine(load(self.residual), m.device)
                self.model_info["residual_net"] = "trained (--residual)"
            elif m.residual_net is None:
                from x2video.model.residual import ResidualNet, engine

                torch.manual_seed(0)
                m.residual_net = engine(ResidualNet(), m.device)
                self.model_info["residual_net"] = ("randomly initialised ResidualNet (no residual.safetensors beside the weights; its "
                                                   "zero-initialised output layer makes tier 1 equal the formula)")
            else:
                self.model_info["residual_net"] = "shipped"
            self.model_info["has_lcm"] = bool(m.has_lcm)
            self.model_info["auto_uses_tier1"] = bool(getattr(m, "residual_auto", True))  # residual.json 'auto'; see tiers.choose_tier
            m.encode_prompts([""])  # load the text encoder before any clock runs
            self._model = m
        return self._model


def _patch(shape: tuple[int, int]) -> tuple[slice, slice]:
    h, w = shape
    return slice(h // 4, max(h // 4 + 1, h // 2)), slice(w // 4, max(w // 4 + 1, w // 2))


HOSTILE: dict[str, Callable[[str, np.ndarray], np.ndarray]] = {}


def _hostile(name: str, channel: str, fn: Callable[[np.ndarray], np.ndarray]) -> None:
    HOSTILE[name] = lambda ch, a: fn(a.copy()) if ch == channel else a


def _set_patch(v: float) -> Callable[[np.ndarray], np.ndarray]:
    def f(a: np.ndarray) -> np.ndarray:
        a[_patch(a.shape[:2])] = v
        return a
    return f


_hostile("nan_irradiance", "irradiance", _set_patch(np.nan))
_hostile("posinf_irradiance", "irradiance", _set_patch(np.inf))
_hostile("neginf_irradiance", "irradiance", _set_patch(-np.inf))
_hostile("irradiance_1e6", "irradiance", _set_patch(1e6))
_hostile("nan_albedo", "albedo", _set_patch(np.nan))
_hostile("negative_roughness", "roughness", lambda a: a * 0 - 0.5)
_hostile("zero_normals", "normal", lambda a: a * 0)
_hostile("albedo_0", "albedo", lambda a: a * 0)
_hostile("albedo_1", "albedo", lambda a: a * 0 + 1)


def poisson_noise(spp: int) -> Callable[[str, np.ndarray, int], np.ndarray]:
    """Irradiance x k/spp per pixel, k ~ Poisson(spp) shared by R, G, B: an unbiased estimate with relative
    standard deviation 1/sqrt(spp) and (at low spp) many black pixels, as a path tracer's few samples give."""

    def f(name: str, a: np.ndarray, t: int) -> np.ndarray:
        if name != "irradiance":
            return a
        rng = np.random.default_rng([spp, t])
        k = rng.poisson(spp, a.shape[:2]).astype(np.float32) / spp
        return (a * k[..., None]).astype(np.float32)
    return f


def cycles_noise(src: Shot) -> Callable[[str, np.ndarray, int], np.ndarray] | None:
    """The irradiance as Cycles sampled it (NoisyDiffDir + NoisyDiffInd, exposure-normalised like the
    denoised one), for a source shot from Cycles EXRs with those layers; None otherwise."""
    from x2video.train.residual_stage import noisy_irradiance

    folder = Path(str(src.info.source))
    files = sorted(folder.glob("*.exr")) if folder.is_dir() else []
    if len(files) != src.num_frames or noisy_irradiance(files[0]) is None:
        return None
    s = float(src.info.irradiance_scale)

    def f(name: str, a: np.ndarray, t: int) -> np.ndarray:
        if name != "irradiance":
            return a
        raw = noisy_irradiance(files[t])
        return (raw * s).astype(np.float32) if raw is not None and raw.shape == a.shape else a
    return f


def build_case(cell: dict, ctx: Context) -> tuple[Shot, Any, Callable[[int], np.ndarray] | None, tuple[str, ...]]:
    """(shot, edits or None, per-frame class map or None, class names) of a cell."""
    from x2video.edits import Edits
    from x2video.edits.masks import Mask
    from x2video.edits.ops import MaskOut

    fam, p = cell["family"], cell["params"]
    src = ctx.sources[p.get("source", 0) % len(ctx.sources)]
    frames = p.get("frames", 2)
    size = tuple(p["size"][::-1]) if "size" in p else None  # params hold [W, H]
    edits, classes, names = None, None, ()
    if fam == "channels":
        shot = ViewShot(src, frames, size)
        edits = Edits()
        edits.dropped = set(INTRINSIC) - set(p["kept"])
    elif fam == "masks":
        shot = ViewShot(src, frames, size)
        n = p["masks"]
        edits = Edits()
        if n:
            ids = _largest_ids(shot, n) if shot.has("ids") else []
            h, w = shot.size
            for i in range(n):
                name = f"m{i}"
                if i < len(ids):
                    edits.masks[name] = Mask(ids=[ids[i]])
                else:  # rectangles on a grid where the shot has too few objects
                    r = np.zeros((h, w), np.float32)
                    gy, gx = divmod(i, 4)
                    r[gy * h // 4:(gy + 1) * h // 4, gx * w // 4:(gx * w // 4) + max(1, w // 8)] = 1
                    edits.masks[name] = Mask(frames={0: r}, hold=True)
                edits.ops.append(MaskOut(mask=name))
                if p.get("local_prompts"):
                    caps = shot.info.object_captions
                    edits.local_prompts[name] = caps.get(ids[i], "a textured surface") if i < len(ids) else "a textured surface"
        frozen = edits

        def classes(t: int) -> np.ndarray:
            from x2video.edits import apply_edits

            return (apply_edits(shot, frozen, t).amr_mask > 0.5).astype(np.int8)
        names = CLASS_SETS["masks"]
    elif fam in ("length", "size"):
        shot = ViewShot(src, frames, size)
    elif fam == "noise":
        tr = cycles_noise(src) if p["noise"] == "cycles" else poisson_noise(int(p["spp"]))
        if tr is None:
            raise LookupError("the source shot has no NoisyDiffDir/NoisyDiffInd layers (not a Cycles shot)")
        shot = ViewShot(src, frames, size, tr)
    elif fam == "hostile":
        fn = HOSTILE[p["case"]]
        shot = ViewShot(src, frames, size, lambda n, a, t: fn(n, a))
    elif fam == "limits":
        shot = ViewShot(src, frames, size)
        clean = shot

        def classes(t: int) -> np.ndarray:
            return limitation_classes(clean.frame(t, ("normal", "metallic", "roughness")))
        names = CLASS_SETS["limits"]
    else:
        raise ValueError(f"unknown family {fam!r}")
    return shot, edits, classes, names


def _largest_ids(shot: Shot, n: int) -> list[int]:
    """The n largest objects of frame 0 that cover under 15% of it (floor, walls and ceiling are not edits' targets)."""
    ids = shot.channel("ids", 0)[..., 0].ravel()
    vals, counts = np.unique(ids[ids > 0], return_counts=True)
    keep = counts < 0.15 * ids.size
    vals, counts = vals[keep], counts[keep]
    return [int(v) for v in vals[np.argsort(-counts)][:n]]


# --------------------------------------------------------------------------------------------- one cell
def skip_reason(cell: dict, ctx: Context) -> str | None:
    """Why a cell is not run (the diffusion tier at sizes and lengths a 2-core CPU cannot afford), else None."""
    from x2video.sampling import tiers

    if not tiers.windowed(cell["method"]):  # the sampler's windows are what a 2-core CPU cannot afford at these sizes
        return None
    p = cell["params"]
    w, h = p.get("size", [0, 0])
    if w * h > ctx.diffusion_max_pixels:
        return f"diffusion skipped above {ctx.diffusion_max_pixels} pixels a frame (--diffusion-max-pixels)"
    if p.get("frames", 2) > ctx.diffusion_max_frames:
        return f"diffusion skipped above {ctx.diffusion_max_frames} frames (--diffusion-max-frames)"
    return None


def run_cell(cell: dict, ctx: Context) -> dict:
    """Render one cell ({family, name, method, params}) and score it; never raises: an exception is recorded
    (crashed, error) with the numbers measured so far. seconds excludes scoring and the model's load."""
    from x2video.sampling import tiers
    from x2video.sampling.events import RenderSettings
    from x2video.sampling.renderer import Renderer

    rec: dict[str, Any] = {k: cell[k] for k in ("family", "name", "method")} | {"params": cell["params"], "crashed": False, "error": None}
    why = skip_reason(cell, ctx)
    if why:
        rec.update(skipped=why)
        return rec
    method = cell["method"]
    needs_model = tiers.needs_model(method)
    model = ctx.model() if needs_model else None
    scorer = None
    release_memory()
    reset_peak_rss()
    base = rss_mb()
    t0 = time.perf_counter()
    try:
        shot, edits, classes, names = build_case(cell, ctx)
        rec["size"] = [shot.size[1], shot.size[0]]
        rec["frames"] = shot.num_frames
        scorer = Scorer(shot, float(shot.info.irradiance_scale), classes, names, delta_e=cell["family"] == "length")
        settings = RenderSettings(quality=method, preset="fast" if needs_model else None)
        if model is None:
            Renderer(None).render(shot, edits, settings, scorer.on_event)  # tier 0 needs no model
        else:
            renderer = Renderer(model)  # a fresh conditioning cache: no cell profits from another
            renderer.render(shot, edits, settings, scorer.on_event)
            choice = getattr(renderer, "last_tier", None)
            if choice is not None:
                rec["tier"] = choice.tier + ("+" + choice.base if choice.regions else "")
                rec["tier_reason"] = choice.reason
    except Exception as exc:
        rec["crashed"] = True
        rec["error"] = f"{type(exc).__name__}: {exc}"[:400]
        last = traceback.extract_tb(exc.__traceback__)[-1]
        rec["where"] = f"{Path(last.filename).name}:{last.lineno} ({last.name})"
    if scorer is not None and scorer.per_frame:  # scored apart: a failure of the measurement is not the product's
        try:
            rec.update(scorer.result(rec.get("frames", 0)))
        except Exception as exc:  # noqa: BLE001
            rec["score_error"] = f"{type(exc).__name__}: {exc}"[:400]
    rec["seconds"] = time.perf_counter() - t0 - (scorer.seconds if scorer is not None else 0.0)
    rec["peak_rss_mb"] = peak_rss_mb()
    rec["peak_rss_above_start_mb"] = max(0.0, rec["peak_rss_mb"] - base)
    return rec


# --------------------------------------------------------------------------------------------- the grid
ALL_SUBSETS = [tuple(c for c, keep in zip(INTRINSIC, bits) if keep) for bits in itertools.product((1, 0), repeat=5)]


def subset_name(kept: tuple[str, ...]) -> str:
    return "+".join(c[:3] for c in kept) if kept else "none"


def grid(quick: bool, n_sources: int, has_cycles: bool, families: tuple[str, ...], methods: tuple[str, ...]) -> list[dict]:
    """The cells: (family, name, method, params) for each family and method."""
    cases: list[tuple[str, str, dict]] = []
    if quick:
        subsets = [s for s in ALL_SUBSETS if len(s) in (0, 5) or s in (("albedo", "irradiance"), ("albedo", "normal", "roughness", "metallic"),
                                                                        ("normal", "roughness", "metallic", "irradiance"))]
        masks = [(0, False), (1, False), (1, True), (16, False), (16, True)]
        lengths = [1, 2, 17, 65]
        sizes = [(8, 8), (13, 11), (64, 64), (100, 75), (333, 217), (1920, 1080)]
        spps = [1, 16, 128]
        hostile = list(HOSTILE)
        limits = [(i, 3) for i in sorted({0, n_sources - 1})]  # first and last shot (pt160: a mirror room, a window room)
    else:
        subsets = ALL_SUBSETS
        masks = [(n, lp) for n in (0, 1, 2, 4, 8, 16) for lp in (False, True) if n or not lp]
        lengths = [1, 2, 17, 65, 257, 1000]
        sizes = [(8, 8), (9, 7), (13, 11), (16, 16), (31, 17), (64, 64), (100, 75), (160, 112), (333, 217), (640, 360), (1001, 563),
                 (1280, 720), (1920, 1080)]
        spps = [1, 2, 4, 8, 16, 32, 64, 128]
        hostile = list(HOSTILE)
        limits = [(i, 8) for i in range(n_sources)]
    if "channels" in families:
        cases += [("channels", subset_name(s), {"kept": list(s), "frames": 2}) for s in subsets]
    if "masks" in families:
        cases += [("masks", f"{n}{'+prompts' if lp else ''}", {"masks": n, "local_prompts": lp, "frames": 2}) for n, lp in masks]
    if "length" in families:
        cases += [("length", f"{n}f", {"frames": n}) for n in lengths]
    if "size" in families:
        cases += [("size", f"{w}x{h}", {"size": [w, h], "frames": 2}) for w, h in sizes]
    if "noise" in families:
        if has_cycles:
            cases.append(("noise", "cycles_noisy", {"noise": "cycles", "frames": 2 if quick else 8}))
        cases += [("noise", f"{s}spp", {"noise": "poisson", "spp": s, "frames": 2}) for s in spps]
    if "hostile" in families:
        cases += [("hostile", h, {"case": h, "frames": 2}) for h in hostile]
    if "limits" in families:
        cases += [("limits", f"shot{i}", {"source": i, "frames": n}) for i, n in limits]
    cases.sort(key=lambda c: FAMILIES.index(c[0]))  # stable: FAMILIES' order, size last
    return [{"family": f, "name": n, "method": m, "params": p} for f, n, p in cases for m in methods]


# --------------------------------------------------------------------------------------------- findings
def findings(cells: list[dict]) -> list[dict]:
    """Failures: a crash, non-finite output, or a PSNR more than FAR_BELOW_DB under the formula's on the same case."""
    from x2video.sampling.tiers import FORMULA

    formula = {(c["family"], c["name"]): c for c in cells if c["method"] == FORMULA}
    out = []
    for c in cells:
        if c.get("skipped"):
            continue
        kind = None
        if c["crashed"]:
            kind = "crash"
        elif c.get("nonfinite_frac", 0) > 0:
            kind = "non-finite output"
        elif c.get("mean_display") == 0.0:
            kind = "black frames"
        elif c["method"] != FORMULA:
            f = formula.get((c["family"], c["name"]))
            if f and not f["crashed"] and c.get("psnr") is not None and f.get("psnr") is not None and c["psnr"] < f["psnr"] - FAR_BELOW_DB:
                kind = f"{f['psnr'] - c['psnr']:.1f} dB below the formula"
        if kind:
            out.append({"family": c["family"], "name": c["name"], "method": c["method"], "failure": kind, "error": c.get("error"),
                        "tier": c.get("tier")})
    return out


# --------------------------------------------------------------------------------------------- report
def merge_results(outs: list[dict]) -> dict:
    """One result from several runs: the first's header, but the model record of the last run that has one (the cells
    of the tiers it loads replace the earlier runs') and the longest list of source shots; every run's cells (a later
    run's cell replaces an earlier one of the same family, case and method, in place), the commands joined, findings
    recomputed."""
    merged = dict(outs[0])
    models = [o["model"] for o in outs if o.get("model")]
    if models:
        merged["model"] = models[-1]
    if any("sources" in o for o in outs):
        merged["sources"] = max((o.get("sources", []) for o in outs), key=len)
    cells: dict[tuple[str, str, str], dict] = {}
    for i, o in enumerate(outs):
        for c in o["cells"]:
            cells[(c["family"], c["name"], c["method"])] = {**c, "run": i}  # which run it comes from (the report says)
    merged["cells"] = list(cells.values())
    datas = list(dict.fromkeys(o["data"] for o in outs if o.get("data")))  # every run's data, in order (each run's command names its own)
    if datas:
        merged["data"] = " and ".join(datas)
    merged["command"] = " ; ".join(o["command"] for o in outs)
    merged["wall_seconds"] = sum(o.get("wall_seconds", 0.0) for o in outs)
    merged["findings"] = findings(merged["cells"])
    return merged



def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a reduced grid (a few cells per family, small sizes, short shots)")
    ap.add_argument("--data", type=Path, default=None, help="folder of path-traced shots with rgb ground truth (default: a synthetic shot)")
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--weights", default=None, help="model folder (default: the shipped weights)")
    ap.add_argument("--residual", default=None, help="folder with residual.safetensors (default: the model's, else random init)")
    ap.add_argument("--diffusion-max-pixels", type=int, default=640 * 360)
    ap.add_argument("--diffusion-max-frames", type=int, default=None, help="default 65, 17 with --quick")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--name", default=None, help="results name (default stability, or stability_quick with --quick)")
    ap.add_argument("--no-docs", action="store_true", help="do not write docs/STABILITY.md")
    ap.add_argument("--report", type=Path, nargs="+", default=None,
                    help="only write docs/STABILITY.md from these results JSONs (a later file's cells replace an earlier's)")
    args = ap.parse_args(argv)
    if args.report is not None:
        from bench.stability_report import write_report

        write_report(merge_results([json.loads(p.read_text()) for p in args.report]), DOCS / "STABILITY.md", DOCS / "stability")
        return 0
    import torch

    from bench.common import clean_json, command, results_path
    from x2video.eval.machine import machine_info
    from x2video.io.atomic import write_json_atomic
    from x2video.io.paths import portable_path

    torch.set_num_threads(args.threads)
    sources: list[Shot] = []
    if args.data is not None:
        from x2video.io import load_shot

        for d in sorted(p for p in args.data.iterdir() if (p / "shot.json").is_file()):
            sh = load_shot(d)
            if sh.has("rgb") and all(sh.has(c) for c in INTRINSIC):
                sources.append(sh)
        if not sources:
            raise SystemExit(f"{args.data}: no shot with rgb and the five channels")
    else:
        sources = [SyntheticShot(8, (112, 160))]
    has_cycles = cycles_noise(sources[0]) is not None
    ctx = Context(sources, weights=args.weights, residual=args.residual, diffusion_max_pixels=args.diffusion_max_pixels,
                  diffusion_max_frames=args.diffusion_max_frames or (17 if args.quick else 65), threads=args.threads)
    families = tuple(f for f in args.families.split(",") if f)
    methods = tuple(m for m in args.methods.split(",") if m)
    cells = grid(args.quick, len(sources), has_cycles, families, methods)
    name = args.name or ("stability_quick" if args.quick else "stability")
    dest = results_path("stability", name)
    dest.parent.mkdir(parents=True, exist_ok=True)
    print(f"{len(cells)} cells; sources: {len(sources)} shot(s); results -> {portable_path(dest)}", flush=True)
    results: list[dict] = []
    t_all = time.perf_counter()

    def write() -> dict:
        out = {"format": "x2video-stability", "command": command("stability", argv), "quick": args.quick,
               "data": portable_path(args.data) if args.data else "synthetic (no --data)",
               "sources": [Path(str(s.info.source)).name for s in sources], "threads": args.threads,
               "model": ctx.model_info, "machine": machine_info(ctx._model.device if ctx._model is not None else "cpu"),
               "note": "PSNR on tonemap (clip, sRGB) in the shot's units; TC = warping error / ground truth's (DIS flow, first "
                       f"{TC_FRAMES} frames); seconds exclude scoring and model loading; peak_rss_mb = the process's VmHWM reset "
                       "before each cell (includes the loaded model); delta_e = mean CIE76 Lab dE to the ground truth",
               "wall_seconds": time.perf_counter() - t_all, "cells": results, "findings": findings(results)}
        write_json_atomic(dest, clean_json(out, 4))
        return out

    for i, cell in enumerate(cells):
        rec = run_cell(cell, ctx)
        results.append(rec)
        status = "SKIP" if rec.get("skipped") else ("CRASH " + str(rec["error"]) if rec["crashed"] else "ok")
        print(f"[{i + 1}/{len(cells)}] {rec['family']:8s} {rec['name']:22s} {rec['method']:9s} psnr {rec.get('psnr', float('nan')):6.2f} "
              f"tc {rec.get('tc') if rec.get('tc') is None else round(rec['tc'], 3)} s {rec.get('seconds', 0):7.2f} "
              f"rss {rec.get('peak_rss_mb', 0):7.0f}MB tier {rec.get('tier', '-')} {status}", flush=True)
        if i % 5 == 4:
            write()
    out = write()
    print(f"wrote {portable_path(dest)}; {sum(c['crashed'] for c in results)} crash(es), {len(out['findings'])} finding(s)")
    if not args.no_docs:
        from bench.stability_report import write_report

        write_report(clean_json(out, 4), DOCS / "STABILITY.md", DOCS / "stability")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
