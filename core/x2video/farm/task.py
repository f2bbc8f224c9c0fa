"""The farm's tasks, through the public API into the shared output folder: plan a job (`plan_job`), render a chunk of
frames (`render_chunk`) or a window of a diffusion plan (`render_window`), put a split shot's output in place
(`finish_job`), or render a whole job (a shot or a project) in one task (`render_job`).

Runs inside a Ray worker (or anywhere: it needs only the shared folder). The model is loaded once per worker
process and kept for the next job with the same model options.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from x2video.farm import state
from x2video.farm.jobs import Job

if TYPE_CHECKING:
    from x2video.edits.model import Edits
    from x2video.model.api import RenderModel
    from x2video.render.renderer import Renderer
    from x2video.render.settings import RenderSettings
    from x2video.shot import Shot
    from x2video.weights import ModelOptions

log = logging.getLogger(__name__)

#: per worker process: model options -> loaded model (a worker renders many shots with one model)
_MODELS: dict[str, RenderModel] = {}


def _model(options: ModelOptions) -> RenderModel:
    import x2video

    key = repr(sorted(dataclasses.asdict(options).items()))
    if key not in _MODELS:
        _MODELS.clear()  # one model per worker at a time
        _MODELS[key] = x2video.load_model(**dataclasses.asdict(options))
    return _MODELS[key]


def _renderer(settings: RenderSettings, options: ModelOptions, retain: bool = True) -> Renderer:
    """A Renderer for `settings`: with this worker's model, or none when the tier needs none (the formula: no weights)."""
    from x2video.render.renderer import Renderer
    from x2video.tiers import registry as tiers

    return Renderer(_model(options) if tiers.needs_model(settings.quality) else None, retain=retain)


def load_job(job: Job) -> tuple[Shot, Edits | None, Path | None]:
    """(shot, edits or None, folder that resolves the edits' relative paths) of a job."""
    import x2video

    if job.kind == "project":
        from x2video.edits import load_project

        project = load_project(job.source)
        return x2video.load_shot(project.shot), project.edits, job.source.parent
    return x2video.load_shot(job.source), None, None


def frame_range(job: Job, shot: Shot, settings: RenderSettings) -> tuple[int, int]:
    start, stop = settings.frames or (0, shot.num_frames)
    if not 0 <= start < stop <= shot.num_frames:
        raise ValueError(f"{job.source}: frame range [{start}, {stop}) outside the shot's {shot.num_frames} frames")
    return start, stop


def _threads(threads: int | None) -> None:
    if threads:
        import torch

        torch.set_num_threads(threads)


def plan_job(job: Job, settings: RenderSettings, options: ModelOptions, threads: int | None = None) -> dict[str, Any]:
    """What a shot's render needs, decided on a worker (which keeps the model for the shot's tasks): its tier
    (`Renderer.choose_tier`), frame range, frame rate, and for the diffusion tier its windows (`Renderer.render_plan`).
    Tiers 0 and 1 ('formula', 'residual') are per frame: the farm splits them into frame chunks (`render_chunk`); a
    diffusion render into its windows (`render_window`), or one task (`render_job`)."""

    from x2video.base.plan import uses_base

    _threads(threads)
    shot, edits, base_dir = load_job(job)
    start, stop = frame_range(job, shot, settings)
    planned = _renderer(settings, options).plan_render(shot, edits, settings)
    # a diffusion render over the shot's base (x2video.base.stage) runs as one task: its windows' frames are laid over the
    # base by `Renderer.render`, which `render_windows` does not do
    over_base = uses_base(shot, settings)
    windows = None if planned.per_frame or over_base else [{"frames": list(w.frames), "generate": list(w.generate), "refs": list(w.refs),
                                                            "level": w.level} for w in planned.windows]
    return {"tier": planned.tier, "reason": planned.reason, "per_frame": planned.per_frame, "start": start, "stop": stop,
            "fps": shot.info.fps, "windows": windows}


def render_chunk(job: Job, out: Path, settings: RenderSettings, options: ModelOptions, fmt: state.OutputFormat, frames: tuple[int, int], key_digest: str,
                 run: str = "", threads: int | None = None) -> dict[str, Any]:
    """Render frames [a, b) of a per-frame tier's shot into its staging folder (`x2video.farm.chunks`) with the same
    render call as a single process (`Renderer.render` with `RenderSettings.frames` = (a, b): a tier-0/1 frame depends
    on its own channels and the shot's exposure only), then mark the chunk done; returns its record."""
    from x2video.farm import chunks
    from x2video.io.units import OutputUnits

    out = Path(out)
    a, b = frames
    task = chunks.chunk_id(a, b)
    attempt = chunks.start_task(out, job.name, task, key_digest, run)
    t0 = time.perf_counter()
    _threads(threads)
    shot, edits, base_dir = load_job(job)
    last = [0.0]

    def progress(n: int) -> None:
        now = time.perf_counter()
        if now - last[0] > 0.25:
            last[0] = now
            chunks.update_task(out, job.name, task, frames_done=n)

    staged = chunks.StagedFrames(out, job.name, fmt, OutputUnits.for_shot(shot, settings.exposure), progress=progress)
    sub = dataclasses.replace(settings, frames=(a, b))
    _renderer(settings, options, retain=False).render(shot, edits, sub, on_event=staged, base_dir=base_dir)
    if staged.written != set(range(a, b)):
        raise RuntimeError(f"{job.source}: the render of frames [{a}, {b}) made frames {sorted(staged.written)[:10]}...")
    seconds = time.perf_counter() - t0
    chunks.update_task(out, job.name, task, done=True, frames_done=b - a, seconds=round(seconds, 3))
    return {"task": task, "attempt": attempt, "frames": b - a, "seconds": seconds}


def render_window(job: Job, out: Path, settings: RenderSettings, options: ModelOptions, fmt: state.OutputFormat, index: int, keep: list[int], key_digest: str,
                  run: str, threads: int | None, ref_from: dict[int, int], *produced: dict[str, Any]) -> dict[str, Any]:
    """Render window `index` of a diffusion shot's plan (`Renderer.render_windows`) and stage the frames it is the last
    to make (`keep`; the seam pass makes some frames again later). Its reference latents come from the results of the
    windows that made them: frame f from `produced[ref_from[f]]` (Ray passes those results in once they exist).
    Saves its latents beside its record (a later run reuses a finished window); returns its record with them."""
    import torch

    from x2video.farm import chunks
    from x2video.io.units import OutputUnits

    out = Path(out)
    task = chunks.window_id(index)
    attempt = chunks.start_task(out, job.name, task, key_digest, run)
    t0 = time.perf_counter()
    _threads(threads)
    shot, edits, base_dir = load_job(job)
    refs = {int(f): torch.from_numpy(np.asarray(produced[k]["latents"][f])) for f, k in ref_from.items()}
    staged = chunks.StagedFrames(out, job.name, fmt, OutputUnits.for_shot(shot, settings.exposure), keep=set(keep),
                                 progress=lambda n: chunks.update_task(out, job.name, task, frames_done=n))
    made = _renderer(settings, options, retain=False).render_windows(shot, edits, settings, [index], refs, on_event=staged, base_dir=base_dir)[index]
    if staged.written != set(keep):
        raise RuntimeError(f"{job.source}: window {index} made frames {sorted(staged.written)}, expected {sorted(keep)}")
    latents = {f: v.float().cpu().numpy() for f, v in made.items()}
    chunks.save_latents(out, job.name, task, latents)
    seconds = time.perf_counter() - t0
    chunks.update_task(out, job.name, task, done=True, frames_done=len(keep), seconds=round(seconds, 3))
    return {"task": task, "attempt": attempt, "latents": latents, "seconds": seconds}


def finish_job(job: Job, out: Path, key: dict[str, Any], exposure: Any, fmt: state.OutputFormat, fps: float, frames: tuple[int, int],
               seconds: float, attempt: int) -> dict[str, Any]:
    """Put a split shot's staged frames in place (`chunks.assemble`: rename the EXR folder, or encode the MP4), write
    its done marker and remove its task records; returns the marker."""
    from x2video.farm import chunks
    from x2video.io.units import OutputUnits

    out = Path(out)
    units = OutputUnits.for_shot(load_job(job)[0], exposure) if fmt == "mp4" else OutputUnits()  # EXR frames were written in units
    target = chunks.assemble(out, job.name, fmt, list(range(*frames)), units, fps)
    marker = state.write_marker(out, job, key, target, frames[1] - frames[0], seconds, attempt)
    records = {p.stem: chunks.read_task(out, job.name, p.stem) for p in sorted(chunks.tasks_dir(out, job.name).glob("*.json")) if p.stem != "key"}
    chunks.reset(out, job.name)
    # every task's starts and seconds stay in the status file: which chunk ran where, which ran twice, how long it took
    state.write_status(out, job.name, state="done", frames_done=frames[1] - frames[0], seconds=round(seconds, 2),
                       task_starts={t: r.get("starts") or [] for t, r in records.items()}, task_seconds={t: r.get("seconds") for t, r in records.items()})
    return {**marker, "skipped": False}


def render_job(job: Job, out: Path, settings: RenderSettings, options: ModelOptions, fmt: state.OutputFormat = "exr", fps: float | None = None,
               run: str = "", threads: int | None = None) -> dict[str, Any]:
    """Render `job` to `out` (see `x2video.farm.state` for the layout) and write its done marker; returns the marker.

    A job already finished with the same settings is skipped (its marker comes back with 'skipped': True).
    `threads`: torch's CPU threads (a Ray task gets as many as the CPUs it asked for)."""
    import x2video
    from x2video.io.units import OutputUnits

    out = Path(out)
    key = state.job_key(job, settings, options, fmt, fps)
    done = state.finished(out, job, key)
    if done is not None:
        return {**done, "skipped": True}
    attempt = state.start_attempt(out, job.name, run)
    state.remove_leftovers(out, job.name, fmt)  # a killed attempt's staging folder
    t0 = time.perf_counter()
    try:
        _threads(threads)
        shot, edits, base_dir = load_job(job)
        start, stop = frame_range(job, shot, settings)
        total = stop - start
        state.write_status(out, job.name, frames_total=total)
        render = _renderer(settings, options, retain=False).render
        target = state.output_path(out, job.name, fmt)
        units = OutputUnits.for_shot(shot, settings.exposure)
        frames: set[int] = set()
        last = [0.0]

        with x2video.FrameSink(target, fps=fps or shot.info.fps, expected=list(range(start, stop)), units=units) as sink:

            def on_event(event: Any) -> None:
                sink(event)
                new = getattr(event, "frames", None)
                if isinstance(new, dict):
                    frames.update(new)
                    now = time.perf_counter()
                    if now - last[0] > 0.25 or len(frames) == total:  # progress, a few times a second at most
                        last[0] = now
                        state.write_status(out, job.name, frames_done=len(frames), level=event.level, seconds=round(now - t0, 2))

            render(shot, edits, settings, on_event=on_event, base_dir=base_dir)
        if sink.result is None:
            raise RuntimeError(f"{job.source}: the render ended without writing {target}")
        seconds = time.perf_counter() - t0
        marker = state.write_marker(out, job, key, target, total, seconds, attempt)
        state.write_status(out, job.name, state="done", frames_done=total, seconds=round(seconds, 2))
        return {**marker, "skipped": False}
    except BaseException as exc:
        state.write_status(out, job.name, state="failed", error=f"{type(exc).__name__}: {exc}")
        raise
