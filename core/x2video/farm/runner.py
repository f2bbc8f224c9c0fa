"""`run_farm`: render many jobs on a Ray cluster, one task per shot, with retries, resume and per-shot progress.

Each job becomes one Ray task (`x2video.farm.task.render_job`) asking for `cpus_per_shot` CPUs. A task whose
worker dies (killed, out of memory, machine lost) is run again by Ray up to `retries` times; the retry starts the
shot over (a recursive render keeps its reference latents in memory, so half a shot cannot be kept) after
removing what the dead attempt left. A Python error in a task is not retried: the shot is reported failed and the
others go on. Finished shots (output + done marker, `x2video.farm.state`) are skipped, so running the same command
again resumes a farm that was stopped or that lost shots.
"""
from __future__ import annotations

import logging
import os
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from x2video.farm import state
from x2video.farm.jobs import Job

log = logging.getLogger(__name__)

#: object store cap of a local cluster this module starts (renders pass no large objects through it)
LOCAL_OBJECT_STORE_BYTES = 128 * 1024**2


@dataclass
class FarmResult:
    """What became of each job: its done marker, or the error that stopped it."""

    done: dict[str, dict[str, Any]] = field(default_factory=dict)
    skipped: dict[str, dict[str, Any]] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.failed


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ImportError("x2video farm needs Ray: pip install 'x2video-studio[farm]' (or pip install ray)") from None
    return ray


def connect(address: str | None = None, local_cpus: int | None = None) -> bool:
    """Connect to the Ray cluster at `address` ('auto': the one started on this machine with `ray start`; default
    $RAY_ADDRESS), or start a local one with `local_cpus` CPUs when neither is given. True when this call started
    Ray (the caller shuts it down); False when Ray was already initialised in this process."""
    ray = _import_ray()
    if ray.is_initialized():
        return False
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        ray.init(num_cpus=local_cpus or os.cpu_count() or 1, object_store_memory=LOCAL_OBJECT_STORE_BYTES, include_dashboard=False,
                 log_to_driver=False)
    return True


class ProgressPrinter:
    """Prints one line per shot whenever its state, attempt or frame count changes (reads the status files)."""

    def __init__(self, out: Path, jobs: list[Job], run: str, write: Callable[[str], None] = print) -> None:
        self.out, self.jobs, self.run, self.write = out, jobs, run, write
        self.seen: dict[str, tuple] = {}
        self.width = max((len(j.name) for j in jobs), default=4)

    def line(self, job: Job, text: str) -> None:
        self.write(f"farm {job.name:<{self.width}}  {text}")

    def poll(self, pending: list[Job]) -> None:
        for job in pending:
            s = state.read_status(self.out, job.name)
            if s.get("run") != self.run:
                continue  # not started in this run yet
            sig = (s.get("state"), s.get("attempt"), s.get("frames_done"))
            if sig == self.seen.get(job.name):
                continue
            self.seen[job.name] = sig
            total = s.get("frames_total")
            frames = f"{s.get('frames_done', 0)}/{total if total is not None else '?'} frames"
            level = f", level {s['level']}" if s.get("level") is not None else ""
            self.line(job, f"{s.get('state')}: {frames}{level}, attempt {s.get('attempt')} on {s.get('host')}:{s.get('pid')}"
                           f"{', ' + str(s['seconds']) + ' s' if s.get('seconds') is not None else ''}")


def run_farm(jobs: list[Job], out: str | Path, settings: Any, options: Any, *, fmt: state.OutputFormat = "exr", fps: float | None = None,
             address: str | None = None, local_cpus: int | None = None, cpus_per_shot: float = 1, retries: int = 3, redo: bool = False,
             write: Callable[[str], None] = print, poll_seconds: float = 0.5) -> FarmResult:
    """Render `jobs` into the shared folder `out` on Ray (see the module docstring); returns what became of each.

    `settings` (`x2video.RenderSettings`) and `options` (`x2video.weights.ModelOptions`) apply to every job. Jobs
    finished before with the same settings are skipped; with other settings it is an error naming the marker, unless
    `redo` (render everything again)."""
    t0 = time.perf_counter()
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    result = FarmResult()
    todo: list[Job] = []
    for job in jobs:
        if redo:
            state.marker_path(out, job.name).unlink(missing_ok=True)
        marker = state.finished(out, job, state.job_key(job, settings, options, fmt, fps))
        if marker is not None:
            result.skipped[job.name] = marker
            write(f"farm {job.name}: finished before ({marker.get('finished')}), skipped")
        else:
            todo.append(job)
    if not todo:
        result.seconds = time.perf_counter() - t0
        return result
    ray = _import_ray()
    from x2video.farm.task import render_job

    started = connect(address, local_cpus)
    run = time.strftime("%Y%m%d-%H%M%S-") + uuid.uuid4().hex[:6]
    threads = max(1, int(cpus_per_shot))
    task = ray.remote(render_job)
    refs = {task.options(num_cpus=cpus_per_shot, max_retries=retries, retry_exceptions=False, name=f"x2video-farm:{job.name}")
            .remote(job, out, settings, options, fmt, fps, run, threads): job for job in todo}
    progress = ProgressPrinter(out, todo, run, write)
    write(f"farm: {len(todo)} shot(s) to render ({len(result.skipped)} finished before) on {ray.cluster_resources().get('CPU', 0):g} CPUs, "
          f"run {run}, output {out}")
    pending = list(refs)
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=len(pending), timeout=poll_seconds, fetch_local=True)
            progress.poll([refs[r] for r in pending])
            for ref in ready:
                job = refs[ref]
                try:
                    marker = ray.get(ref)
                except Exception as exc:  # RayTaskError (the render raised) or WorkerCrashedError (retries used up)
                    cause = getattr(exc, "cause", None) or exc
                    result.failed[job.name] = f"{type(cause).__name__}: {cause}".splitlines()[0]
                    state.write_status(out, job.name, state="failed", error=result.failed[job.name])
                    progress.line(job, f"FAILED: {result.failed[job.name]}")
                    continue
                if marker.get("skipped"):
                    result.skipped[job.name] = marker
                else:
                    result.done[job.name] = marker
                n = len(result.done) + len(result.skipped) + len(result.failed)
                progress.line(job, f"done: {marker['frames']} frames in {marker['seconds']:.1f} s (attempt {marker['attempt']}) "
                                   f"[{n}/{len(jobs)}]")
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    finally:
        if started:
            ray.shutdown()
    result.seconds = time.perf_counter() - t0
    return result
