"""`run_farm`: render many jobs on a Ray cluster, with retries, resume and per-shot progress.

Each job starts with a small task (`x2video.farm.task.plan_job`) that decides its tier on a worker. A shot whose
tier is per frame (tier 0, the formula, and tier 1, the residual net: what quality 'auto' renders for a shot with
every channel and nothing to generate) is split into chunks of `chunk_frames` frames, one task each
(`render_chunk`); a diffusion-tier shot into its windows (`render_window`, `Renderer.render_windows`), each
submitted with the results of the windows that made its reference frames as arguments, so Ray starts it once they
exist (the windows of one recursive level run in parallel). The tasks write their frames into the shot's staging
folder (`x2video.farm.chunks`); a last task (`finish_job`) puts the output in place and writes the done marker.
Without `split`, a shot is one task (`render_job`). Every task asks for `cpus_per_shot` CPUs. A task whose worker
dies (killed, out of memory, machine lost) is run again by Ray up to `retries` times: a chunk or window starts over
(its finished frames are whole files, written again identically), chunks and windows marked done are never run
again (a finished window is reused with the latents it saved); a whole-shot task starts the shot over after
removing what the dead attempt left. A Python error in a task is not retried: the shot is reported failed and the others
go on. Finished shots (output + done marker, `x2video.farm.state`) are skipped, so running the same command again
resumes a farm that was stopped or that lost shots (a split shot keeps the chunks or windows it finished).
"""
from __future__ import annotations

import logging
import os
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from x2video.farm import chunks, state
from x2video.farm.chunks import CHUNK_FRAMES
from x2video.farm.jobs import Job

if TYPE_CHECKING:
    from x2video.render.settings import RenderSettings
    from x2video.weights import ModelOptions

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
            sig = (s.get("state"), s.get("attempt"), s.get("frames_done"), s.get("parts_done"), s.get("parts_running"))
            if sig == self.seen.get(job.name):
                continue
            self.seen[job.name] = sig
            total = s.get("frames_total")
            frames = f"{s.get('frames_done', 0)}/{total if total is not None else '?'} frames"
            level = f", level {s['level']}" if s.get("level") is not None else ""
            where = (f", {s.get('parts_kind')} {s.get('parts_done')}/{s.get('parts_total')} done, {s.get('parts_running')} running, "
                     f"attempt {s.get('attempt')}" if s.get("parts_total") else f", attempt {s.get('attempt')} on {s.get('host')}:{s.get('pid')}")
            self.line(job, f"{s.get('state')}: {frames}{level}{where}{', ' + str(s['seconds']) + ' s' if s.get('seconds') is not None else ''}")


@dataclass
class _Shot:
    """The driver's view of one job in flight."""

    job: Job
    key: dict[str, Any]
    digest: str
    t0: float
    plan: dict[str, Any] | None = None
    parts: dict[str, list[int]] = field(default_factory=dict)  # task (a chunk or a window) -> the frames it stages
    kind: str = ""  # 'chunks' or 'windows' when split
    done: set[str] = field(default_factory=set)
    attempts: dict[str, int] = field(default_factory=dict)
    status: tuple = ()
    finishing: bool = False


def run_farm(jobs: list[Job], out: str | Path, settings: RenderSettings, options: ModelOptions, *, fmt: state.OutputFormat = "exr", fps: float | None = None,
             address: str | None = None, local_cpus: int | None = None, cpus_per_shot: float = 1, retries: int = 3, redo: bool = False,
             chunk_frames: int = CHUNK_FRAMES, split: bool = True, write: Callable[[str], None] = print, poll_seconds: float = 0.5) -> FarmResult:
    """Render `jobs` into the shared folder `out` on Ray (see the module docstring); returns what became of each.

    `settings` (`x2video.RenderSettings`) and `options` (`x2video.weights.ModelOptions`) apply to every job. Jobs
    finished before with the same settings are skipped; with other settings it is an error naming the marker, unless
    `redo` (render everything again). A shot whose tier is per frame (tiers 0 and 1) runs as tasks of `chunk_frames`
    frames each, a diffusion shot as one task per window (each starts once the windows it reads are done); not
    `split`: one task per shot. `cpus_per_shot` is what each task asks for."""
    t0 = time.perf_counter()
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    if chunk_frames < 1:
        raise ValueError(f"chunk_frames must be at least 1, got {chunk_frames}")
    result = FarmResult()
    todo: list[Job] = []
    for job in jobs:
        if redo:
            state.marker_path(out, job.name).unlink(missing_ok=True)
            chunks.reset(out, job.name)
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
    from x2video.farm import task as tasks

    started = connect(address, local_cpus)
    run = time.strftime("%Y%m%d-%H%M%S-") + uuid.uuid4().hex[:6]
    threads = max(1, int(cpus_per_shot))
    opts = {"num_cpus": cpus_per_shot, "max_retries": retries, "retry_exceptions": False}
    remote = {f: ray.remote(getattr(tasks, f)) for f in ("plan_job", "render_chunk", "render_window", "finish_job", "render_job")}
    refs: dict[Any, tuple[_Shot, str, str]] = {}  # object ref -> (shot, kind, task name)

    def submit(shot: _Shot, kind: str, name: str, *args: Any) -> Any:
        ref = remote[kind].options(**opts, name=f"x2video-farm:{shot.job.name}:{name}").remote(*args)
        refs[ref] = (shot, kind, name)
        return ref

    shots = {}
    for job in todo:
        key = state.job_key(job, settings, options, fmt, fps)
        shot = shots[job.name] = _Shot(job, key, chunks.digest(key), time.perf_counter())
        submit(shot, "plan_job", "plan", job, settings, options, threads)
    progress = ProgressPrinter(out, todo, run, write)
    write(f"farm: {len(todo)} shot(s) to render ({len(result.skipped)} finished before) on {ray.cluster_resources().get('CPU', 0):g} CPUs, "
          f"run {run}, output {out}")

    def fail(shot: _Shot, error: str) -> None:
        result.failed[shot.job.name] = error
        for ref, (other, _, _) in list(refs.items()):
            if other is shot:
                ray.cancel(ref, force=True)
                del refs[ref]
        state.write_status(out, shot.job.name, state="failed", error=error)
        progress.line(shot.job, f"FAILED: {error}")

    def finish(shot: _Shot, marker: dict[str, Any]) -> None:
        (result.skipped if marker.get("skipped") else result.done)[shot.job.name] = marker
        n = len(result.done) + len(result.skipped) + len(result.failed)
        progress.line(shot.job, f"done: {marker['frames']} frames in {marker['seconds']:.1f} s (attempt {marker['attempt']}"
                                f"{', ' + str(len(shot.parts)) + ' ' + shot.kind if shot.parts else ''}) [{n}/{len(jobs)}]")

    def planned(shot: _Shot, plan: dict[str, Any]) -> None:
        shot.plan = plan
        job = shot.job
        if not split or not (plan["per_frame"] or plan.get("windows")):  # one task renders the shot
            submit(shot, "render_job", "render", job, out, settings, options, fmt, fps, run, threads)
            return
        chunks.begin(out, job.name, shot.digest)
        results: dict[int, Any] = {}  # window -> its task's result (an object ref) or the latents a finished window saved
        if plan["per_frame"]:
            shot.kind = "chunks"
            ranges = chunks.chunk_ranges(plan["start"], plan["stop"], chunk_frames)
            shot.parts = {chunks.chunk_id(a, b): list(range(a, b)) for a, b in ranges}
        else:
            shot.kind = "windows"
            windows = plan["windows"]
            final = {f: i for i, w in enumerate(windows) for f in w["generate"]}  # the last window to make each frame
            shot.parts = {chunks.window_id(i): [f for f in w["generate"] if final[f] == i] for i, w in enumerate(windows)}
        shot.done = {t for t, frames in shot.parts.items() if chunks.task_done(out, job.name, t, shot.digest, frames, fmt)}
        if shot.kind == "windows":  # a finished window is reused only with its latents
            for t in list(shot.done):
                latents = chunks.load_latents(out, job.name, t)
                if latents is None:
                    shot.done.discard(t)
                else:
                    results[int(t[1:])] = {"latents": latents}
        state.write_status(out, job.name, state="running", run=run, attempt=1, host=None, pid=None, frames_total=plan["stop"] - plan["start"],
                           frames_done=0, level=None, error=None, started=time.time(), tier=plan["tier"], parts_kind=shot.kind,
                           parts_total=len(shot.parts), parts_done=len(shot.done), parts_reused=len(shot.done), parts_running=0)
        if shot.kind == "chunks":
            for t, frames in shot.parts.items():
                if t not in shot.done:
                    submit(shot, "render_chunk", t, job, out, settings, options, fmt, (frames[0], frames[-1] + 1), shot.digest, run, threads)
        else:
            made_by: dict[int, int] = {}  # frame -> the latest window that made it (what a later window reads)
            for i, w in enumerate(plan["windows"]):
                t = chunks.window_id(i)
                if t not in shot.done:
                    deps = sorted({made_by[f] for f in w["refs"]})
                    ref_from = {f: deps.index(made_by[f]) for f in w["refs"]}
                    # Ray starts the window once the results of the windows it reads exist (object refs as arguments)
                    results[i] = submit(shot, "render_window", t, job, out, settings, options, fmt, i, shot.parts[t], shot.digest, run,
                                        threads, ref_from, *[results[k] for k in deps])
                made_by.update({f: i for f in w["generate"]})
        part_progress(shot)

    def part_progress(shot: _Shot) -> None:
        """Sum the part records into the shot's status (the driver is its only writer while parts run); finish when all are done."""
        job = shot.job
        frames_done, running, attempt = 0, 0, 1
        for t, frames in shot.parts.items():
            if t in shot.done:
                frames_done += len(frames)
                continue
            rec = chunks.read_task(out, job.name, t)
            if not rec.get("done") and any(s.get("run") == run for s in rec.get("starts") or []):
                running += 1
                frames_done += int(rec.get("frames_done") or 0)
                attempt = max(attempt, int(rec.get("attempt") or 1))
        sig = (frames_done, running, len(shot.done), attempt)
        if sig != shot.status:
            shot.status = sig
            state.write_status(out, job.name, frames_done=frames_done, parts_done=len(shot.done), parts_running=running, attempt=attempt,
                               seconds=round(time.perf_counter() - shot.t0, 2))
        if len(shot.done) == len(shot.parts) and not shot.finishing:
            shot.finishing = True
            plan = shot.plan or {}
            attempts = [a for a in shot.attempts.values()] or [1]
            submit(shot, "finish_job", "finish", job, out, shot.key, settings.exposure, fmt, fps or plan["fps"], (plan["start"], plan["stop"]),
                   time.perf_counter() - shot.t0, max(attempts))

    try:
        while refs:
            # back as soon as one task ends (the next stage of its shot starts at once), with every other that ended too
            ready, rest = ray.wait(list(refs), num_returns=1, timeout=poll_seconds, fetch_local=True)
            if ready and rest:
                ready += ray.wait(rest, num_returns=len(rest), timeout=0, fetch_local=True)[0]
            for ref in ready:
                if ref not in refs:  # cancelled with its shot's failure
                    continue
                shot, kind, name = refs.pop(ref)
                try:
                    value = ray.get(ref)
                except Exception as exc:  # RayTaskError (the render raised) or WorkerCrashedError (retries used up)
                    cause = getattr(exc, "cause", None) or exc
                    fail(shot, f"{type(cause).__name__}: {cause}".splitlines()[0] + ("" if kind in ("plan_job", "render_job") else f" ({name})"))
                    continue
                if kind == "plan_job":
                    planned(shot, value)
                elif kind in ("render_chunk", "render_window"):
                    shot.done.add(name)
                    shot.attempts[name] = value["attempt"]
                elif kind in ("render_job", "finish_job"):
                    finish(shot, value)
            for shot in shots.values():
                if shot.parts and not shot.finishing and shot.job.name not in result.failed:
                    part_progress(shot)
            progress.poll([s.job for s in shots.values() if s.job.name not in result.done and s.job.name not in result.failed])
    except BaseException:
        for ref in refs:
            ray.cancel(ref, force=True)
        raise
    finally:
        if started:
            ray.shutdown()
    result.seconds = time.perf_counter() - t0
    return result
