"""One farm task: render one job (a shot or a project) through the public API into the shared output folder.

Runs inside a Ray worker (or anywhere: it needs only the shared folder). The model is loaded once per worker
process and kept for the next job with the same model options.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import Any

from x2video.farm import state
from x2video.farm.jobs import Job

log = logging.getLogger(__name__)

#: per worker process: model options -> loaded model (a worker renders many shots with one model)
_MODELS: dict[str, Any] = {}


def _model(options: Any) -> Any:
    import x2video

    key = repr(sorted(dataclasses.asdict(options).items()))
    if key not in _MODELS:
        _MODELS.clear()  # one model per worker at a time
        _MODELS[key] = x2video.load_model(**dataclasses.asdict(options))
    return _MODELS[key]


def render_job(job: Job, out: Path, settings: Any, options: Any, fmt: state.OutputFormat = "exr", fps: float | None = None,
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
        if threads:
            import torch

            torch.set_num_threads(threads)
        edits, base_dir = None, None
        if job.kind == "project":
            from x2video.edits import load_project

            project = load_project(job.source)
            shot = x2video.load_shot(project.shot)
            edits, base_dir = project.edits, job.source.parent
        else:
            shot = x2video.load_shot(job.source)
        start, stop = settings.frames or (0, shot.num_frames)
        if not 0 <= start < stop <= shot.num_frames:
            raise ValueError(f"{job.source}: frame range [{start}, {stop}) outside the shot's {shot.num_frames} frames")
        total = stop - start
        state.write_status(out, job.name, frames_total=total)
        if settings.quality == "formula":  # no network, no weights (as `x2video render --quality formula`)
            from x2video.sampling.formula import formula_frames as render
        else:
            render = x2video.Renderer(_model(options)).render
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
