"""`evaluate`: renders the held-out shots for every row of the requested tables and scores model and classical baseline.

Each distinct render (model, condition, sampler, steps, scheme, data) runs once; rows that
repeat it (e.g. table a's video model = table b's full channels = table d's DDIM row) point to
it with `same_render_as`. Every render starts with an empty conditioning cache, so its seconds
per frame include encoding the channels, like a fresh render in the editor; each model and
sampler gets one untimed warm-up render first.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from x2video.eval.baseline import DESCRIPTION as BASELINE_DESCRIPTION
from x2video.eval.baseline import classical_frames
from x2video.eval.conditions import build_edits
from x2video.eval.config import EvalConfig
from x2video.eval.data import GROUND_TRUTH, EvalShot, EvalView
from x2video.eval.machine import machine_info
from x2video.eval.scoring import Scorer
from x2video.eval.tables import PAPER, PAPER_NOTE, TITLES, RowSpec, table_rows
from x2video.io.truth import summary as truth_summary
from x2video.metrics.suite import DEFINITIONS
from x2video.metrics.unavailable import unavailable_metrics
from x2video.model.api import RenderModel
from x2video.render.events import Cancelled, CancelToken, FramesReady, RenderCancelled
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings

if TYPE_CHECKING:
    from x2video.edits.model import Edits

log = logging.getLogger(__name__)

MISSING_IMAGE = "no image-stage weights given (pass --image-weights IMAGE_RUN from `x2video train image`)"
MISSING_LCM = (
    "no LCM weights: pass --lcm-weights LCM_RUN (from `x2video train lcm`) or --weights holding lcm_unet.safetensors"
)


@dataclass
class EvalModels:
    """The models rows refer to by role: "video" (required), "image" and "lcm" (optional)."""

    video: RenderModel
    image: RenderModel | None = None
    lcm: RenderModel | None = None
    info: dict[str, dict] = field(default_factory=dict)
    """role -> description recorded in results.json (path, config name, untrained flag ...)"""

    def __post_init__(self) -> None:
        if self.lcm is None and getattr(self.video, "has_lcm", False):
            self.lcm = self.video
        if self.lcm is not None and not self.lcm.has_lcm:
            raise ValueError("the LCM model has no distilled (lcm_unet) weights")

    def get(self, role: str) -> RenderModel | None:
        return {"video": self.video, "image": self.image, "lcm": self.lcm}[role]

    def missing_reason(self, role: str) -> str:
        return {"image": MISSING_IMAGE, "lcm": MISSING_LCM}.get(role, f"no {role} model")


@dataclass
class EvalProgress:
    """Emitted before each shot of a row is rendered ("render") and when a row is done ("row")."""

    done: int  # shot renders finished so far
    total: int  # shot renders planned (rows sharing a render count once)
    table: str
    label: str
    shot: str | None
    what: str


def render_shot(renderer: Renderer, shot: EvalShot, edits: Edits | None, settings: RenderSettings,
                cancel: CancelToken | None = None) -> tuple[list[np.ndarray], float]:
    """(T linear frames, wall seconds) of one full render, conditioning cache emptied first
    (`renderer.encode_seconds` then holds the part of it spent encoding the channels)."""
    frames: dict[int, np.ndarray] = {}
    cancelled: list[bool] = []

    def on_event(e: Any) -> None:
        if isinstance(e, FramesReady):
            frames.update(e.frames)
        elif isinstance(e, RenderCancelled):
            cancelled.append(True)

    renderer.cache.clear()
    t0 = time.perf_counter()
    renderer.render(shot.shot, edits, settings, on_event=on_event, cancel=cancel)
    seconds = time.perf_counter() - t0
    if cancelled:
        raise Cancelled(f"evaluation cancelled while rendering shot {shot.name!r}")
    missing = [t for t in range(shot.num_frames) if t not in frames]
    if missing:
        raise RuntimeError(f"shot {shot.name!r}: the renderer produced no frame(s) {missing[:8]}")
    return [frames[t] for t in range(shot.num_frames)], seconds


def warm_up(renderer: Renderer, shot: EvalShot, sampler: str) -> None:
    """One untimed 2-frame, 1-step render, so one-off costs (first calls, allocator growth, text encoder
    start-up) do not land in the first timed row."""
    view = EvalShot(shot.name, shot.path, EvalView(shot.shot, frames=2), None, shot.gt[:2])
    render_shot(renderer, view, None, RenderSettings(sampler=sampler, steps=1, window=2, base="off"))  # type: ignore[arg-type]


def _settings(spec: RowSpec, config: EvalConfig, num_frames: int) -> RenderSettings:
    window = max(2, min(num_frames, config.image_window)) if spec.model == "image" else config.window
    return RenderSettings(sampler=spec.sampler, steps=spec.steps, seed=config.seed, window=window, scheme=spec.scheme,  # type: ignore[arg-type]
                          replace_refs=config.replace_refs, seams=config.seams, max_levels=config.max_levels, noise=config.noise,  # type: ignore[arg-type]
                          noise_shared=config.noise_shared, resample=config.resample,
                          ref_dc=config.ref_dc, base="off")  # scored against the shot's own rgb: never return it


def evaluate(
    models: EvalModels,
    data: dict[str, list[EvalShot]],
    config: EvalConfig,
    on_progress: Callable[[EvalProgress], None] | None = None,
    cancel: CancelToken | None = None,
    on_frames: Callable[[RowSpec, EvalShot, list[np.ndarray]], None] | None = None,
) -> dict[str, Any]:
    """Run every requested table; returns the JSON-able results (see `x2video.eval.report` for the Markdown).

    `data`: "main" shots (tables a, b, d) and "long" shots (table c; "main" when absent).
    `on_frames(row, shot, frames)` receives each render's linear frames (contact sheets); they
    are not kept otherwise."""
    t_start = time.perf_counter()
    emit = on_progress or (lambda p: None)
    if "main" not in data or not data["main"]:
        raise ValueError("evaluate: no held-out shots")
    data = {"main": data["main"], "long": data.get("long") or data["main"]}
    specs = table_rows(config)
    scorers = {k: Scorer(v, fid=config.fid, tc=config.tc) for k, v in data.items()}
    renderers: dict[int, Renderer] = {}
    warmed: set[tuple[int, str]] = set()

    planned, total = set(), 0
    for rows in specs.values():
        for r in rows:
            if models.get(r.model) is not None and r.render_key() not in planned:
                planned.add(r.render_key())
                total += len(data[r.data])
    done = 0
    renders: dict[tuple, tuple[str, dict]] = {}  # render key -> (first row's name, model metrics + inputs)
    baselines: dict[tuple, dict] = {}
    tables: dict[str, Any] = {}
    for table, rows in specs.items():
        out_rows = []
        for spec in rows:
            row: dict[str, Any] = {"label": spec.label, "settings": spec.settings(), "condition": spec.condition.to_dict()}
            paper = PAPER.get(table, {}).get(spec.label)
            if paper:
                row["paper"] = paper
            model = models.get(spec.model)
            shots = data[spec.data]
            if model is None:
                row.update(available=False, reason=models.missing_reason(spec.model))
                out_rows.append(row)
                continue
            row["available"] = True
            row["settings"]["window"] = _settings(spec, config, shots[0].num_frames).window
            edits = {s.name: build_edits(s.shot, s.name, spec.condition, config.seed) for s in shots}
            row["inputs"] = {name: desc for name, (_, desc) in edits.items() if desc}
            key = spec.render_key()
            if key in renders:
                row["same_render_as"], row["model"] = renders[key][0], renders[key][1]
            else:
                mid = id(model)
                if mid not in renderers:
                    renderers[mid] = Renderer(model)
                if (mid, spec.sampler) not in warmed:
                    warm_up(renderers[mid], shots[0], spec.sampler)
                    warmed.add((mid, spec.sampler))
                preds, secs, enc = {}, {}, 0.0
                for s in shots:
                    emit(EvalProgress(done, total, table, spec.label, s.name, "render"))
                    preds[s.name], secs[s.name] = render_shot(renderers[mid], s, edits[s.name][0], _settings(spec, config, s.num_frames), cancel)
                    enc += renderers[mid].encode_seconds
                    if on_frames is not None:
                        on_frames(spec, s, preds[s.name])
                    done += 1
                row["model"] = scorers[spec.data].score(preds, secs)
                # the once-per-shot channel encoding inside seconds_per_frame (the editor caches it across re-renders)
                row["model"]["encode_seconds_per_frame"] = enc / max(1, sum(s.num_frames for s in shots))
                renders[key] = (f"{table}: {spec.label}", row["model"])
            bkey = spec.baseline_key()
            if bkey not in baselines:
                frames, secs = {}, {}
                for s in shots:
                    frames[s.name], secs[s.name] = classical_frames(s.shot, edits[s.name][0])
                baselines[bkey] = scorers[spec.data].score(frames, secs)
            row["baseline"] = baselines[bkey]
            emit(EvalProgress(done, total, table, spec.label, None, "row"))
            out_rows.append(row)
        tables[table] = {"title": TITLES[table], "rows": out_rows, "notes": _notes(table, config, data)}

    return {
        "format": "x2video-eval",
        "version": 1,
        "tables": tables,
        "settings": config.to_dict(),
        "ground_truth": GROUND_TRUTH,
        "truth": truth_summary(s.truth for shots in data.values() for s in shots),
        "baseline": BASELINE_DESCRIPTION,
        "definitions": dict(DEFINITIONS),
        "unavailable": unavailable_metrics(),
        "paper_note": PAPER_NOTE,
        "machine": machine_info(getattr(models.video, "device", None)),
        "wall_seconds": time.perf_counter() - t_start,
        "metric_seconds": sum(s.seconds for s in scorers.values()),
    }


def _notes(table: str, config: EvalConfig, data: dict[str, list[EvalShot]]) -> list[str]:
    main = data["main"]
    frames = sorted({s.num_frames for s in main})
    notes = []
    if table == "a":
        notes.append(
            "the image model (XRGB-style UNet; 27 inputs with the shading prior) renders every frame independently, "
            f"{config.image_window} frames per UNet call; "
            f"the video model uses Recursive Sampling with N={config.window}"
        )
    if table == "b":
        notes.append(
            f"Mask A|M|R: albedo, metallic and roughness zeroed on {config.masks} random objects per shot (seed {config.seed}); "
            "+ Text: global prompt = shot caption, local prompts = the masked objects' captions; "
            "+ Ref.: ground-truth rgb frame 0 as reference (frame 0 stays in the metrics)"
        )
    if table == "c":
        long_frames = sorted({s.num_frames for s in data["long"]})
        if max(long_frames) < config.long_frames:
            notes.append(f"the long shots have {'/'.join(map(str, long_frames))} frames, fewer than the {config.long_frames} asked: "
                         "generate them with `x2video dataset make --frames 65` and pass --long-data")
        else:
            notes.append(f"{'/'.join(map(str, long_frames))}-frame shots")
    if table == "d":
        notes.append("+ Ref.: ground-truth rgb frame 0 as reference; seconds per frame include encoding the channels and decoding")
    if table != "c":
        notes.append(f"{len(main)} shot(s) of {'/'.join(map(str, frames))} frames")
    return notes


def with_models_info(results: dict[str, Any], models: EvalModels) -> dict[str, Any]:
    """`results` with the models' descriptions (what each role is, or why it is missing)."""
    out = dict(results)
    out["models"] = {role: models.info.get(role, {}) if models.get(role) is not None else {"missing": models.missing_reason(role)}
                     for role in ("video", "image", "lcm")}
    return out


__all__ = ["EvalModels", "EvalProgress", "evaluate", "render_shot", "with_models_info"]
