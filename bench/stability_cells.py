"""One cell of the stability bench (bench.stability): the case built from a source shot, rendered by one method,
scored as frames arrive (PSNR, per-class PSNR, drift, TC), timed, and its peak memory."""
from __future__ import annotations

import math
import re
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from bench.stability_shots import HOSTILE, ViewShot, cycles_noise, poisson_noise, resize_channel
from x2video.channels import INTRINSIC, tonemap
from x2video.shot import Shot

#: frames whose display images are kept for TC (the rest of a long shot is scored frame by frame only)
TC_FRAMES = 65


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
                 delta_e: bool = False, fit_exposure: bool = False, truth: Callable[[int], np.ndarray] | None = None):
        self.gt_shot, self.scale, self.classes, self.class_names, self.delta_e = gt_shot, scale, classes, class_names, delta_e
        self.truth = truth  # frame t's truth when it is not the shot's rgb (a truth apart: `case_truth`)
        self.fit_exposure = fit_exposure  # one exposure per frame fitted to the truth (a truth in another tool's units)
        self.per_frame: dict[int, dict] = {}
        self.keep: dict[int, np.ndarray] = {}
        self.seconds = 0.0

    def gt(self, t: int) -> np.ndarray:
        """Frame t's linear truth: `truth(t)`, else the shot's rgb."""
        return self.truth(t) if self.truth is not None else self.gt_shot.channel("rgb", t)

    def on_event(self, e: Any) -> None:
        from x2video.render.events import FramesReady

        if isinstance(e, FramesReady):
            t0 = time.perf_counter()
            for t, f in e.frames.items():
                self.add(t, f)
            self.seconds += time.perf_counter() - t0

    def add(self, t: int, frame: np.ndarray) -> None:
        frame = np.asarray(frame, np.float32)
        bad = int((~np.isfinite(frame)).sum())
        lin = np.nan_to_num(frame, nan=0.0, posinf=1e6, neginf=0.0) / self.scale
        if self.fit_exposure:
            from bench.stability_foreign import best_exposure

            lin = lin * best_exposure(lin, np.nan_to_num(self.gt(t)), tonemap)
        disp = tonemap(lin)
        gt = tonemap(np.nan_to_num(self.gt(t)))
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

            gts = [tonemap(np.nan_to_num(self.gt(t))) for t in kept]
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
    #: each source's truth (`x2video.io.truth.ground_truth`); empty: every source is scored against its rgb
    truths: list[Any] = field(default_factory=list)
    weights: str | None = None
    residual: str | None = None
    diffusion_max_pixels: int = 1920 * 1080
    diffusion_max_frames: int = 65
    threads: int = 2
    untrained: bool = False
    #: where the foreign family writes its files (a temporary folder made on first use)
    scratch: Path | None = None
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
                from x2video.model.residual import load
                from x2video.model.residual_engine import engine

                m.residual_net = engine(load(self.residual), m.device)
                self.model_info["residual_net"] = "trained (--residual)"
            elif m.residual_net is None:
                from x2video.model.residual import ResidualNet
                from x2video.model.residual_engine import engine

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
            from x2video.conditioning.edited import apply_edits

            return (apply_edits(shot, frozen, t).amr_mask > 0.5).astype(np.int8)
        names = CLASS_SETS["masks"]
    elif fam in ("length", "size"):
        shot = ViewShot(src, frames, size)
    elif fam == "foreign":
        import tempfile

        from bench.stability_foreign import CASES, foreign_shot

        ctx.scratch = ctx.scratch or Path(tempfile.mkdtemp(prefix="x2video-foreign-"))
        shot = foreign_shot(src, frames, CASES[p["case"]], ctx.scratch)
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


def case_truth(cell: dict, ctx: Context, shot: Shot) -> Callable[[int], np.ndarray] | None:
    """Frame t's truth for a cell whose source has a truth apart (``truth/``), at the case's size and in its units
    (the foreign family: through the same fixture and scale as its picture, never through its 8 bits); None where
    the source has none (the case shot's rgb is the truth)."""
    i = cell["params"].get("source", 0) % len(ctx.sources)
    tr = ctx.truths[i] if i < len(ctx.truths) else None
    if tr is None or not tr.apart:
        return None
    if cell["family"] == "foreign":
        from functools import lru_cache

        from bench.stability_foreign import CASES, foreign_channels

        src, case = ctx.sources[i], CASES[cell["params"]["case"]]
        return lru_cache(maxsize=2)(lambda t: foreign_channels(src, t, case, rgb=tr.frame(t))["rgb"])
    return lambda t: resize_channel("rgb", tr.frame(shot.src_index(t)), shot.size)


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
    from x2video.tiers import registry as tiers

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
    from x2video.render.renderer import Renderer
    from x2video.render.settings import RenderSettings
    from x2video.tiers import registry as tiers

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
        scorer = Scorer(shot, float(shot.info.irradiance_scale), classes, names, delta_e=cell["family"] == "length",
                        fit_exposure=cell["family"] == "foreign", truth=case_truth(cell, ctx, shot))
        settings = RenderSettings(quality=method, preset="fast" if needs_model else None, base="off")
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
