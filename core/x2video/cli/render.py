"""`x2video render`: render a shot (optionally with a project's edits) to an MP4 or an EXR folder."""
from __future__ import annotations

import argparse
import dataclasses
import logging
import time
from pathlib import Path
from typing import Any

from x2video.fields import add_fields, from_args
from x2video.io.units import OutputUnits
from x2video.procedural.demo import demo_cache
from x2video.render.events import FramesReady, RenderEvent, RenderStarted, StepDone
from x2video.render.settings import RenderSettings
from x2video.weights import ModelOptions

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "render",
        help="render a shot to video with the X2Video model",
        description="Render SHOT (a shot folder, or --demo) to OUT: a .mp4 file or a folder of EXR frames.",
    )
    p.add_argument("shot", nargs="?", type=Path, help="shot folder (or any layout `x2video info` reads)")
    p.add_argument("--demo", action="store_true", help="render the demo shot: a room path-traced with Cycles on first use (about 2 minutes on a free"
                   " 2-core CPU; the rasterized procedural room where bpy is missing or $X2VIDEO_DEMO_RENDERER=raster)")
    p.add_argument("--demo-dir", type=Path, default=None, help="where the demo shot is cached (default $X2VIDEO_DEMO_DIR, else ~/.cache/x2video/demo)")
    p.add_argument("--project", type=Path, help="project file with edits, masks, prompts and reference frame (its shot is used when SHOT is not given)")
    p.add_argument("--out", type=Path, required=True, help="output: OUT.mp4 (H.264, sRGB) or a folder of linear EXR frames")
    p.add_argument("--fps", type=float, help="MP4 frame rate (default: the shot's)")
    add_fields(p.add_argument_group("sampling (x2video.RenderSettings)"), RenderSettings)
    add_fields(p.add_argument_group("model (x2video.weights.ModelOptions)"), ModelOptions)
    p.set_defaults(func=run)


def load_inputs(args: argparse.Namespace) -> tuple[Any, Any, Path | None]:
    """(shot, edits or None, folder that relative paths in the project refer to).

    The shot is SHOT, the demo shot (--demo), or the shot the --project file names.
    """
    from x2video.io import load_shot

    project = None
    if args.project is not None:
        from x2video.edits import load_project

        project = load_project(args.project)
    if args.shot is not None and args.demo:
        raise ValueError("give either a SHOT folder or --demo, not both")
    if args.shot is None and not args.demo and project is None:
        raise ValueError("nothing to render: give a SHOT folder, --demo, or a --project file")
    if args.demo:
        folder = _demo(args.demo_dir or demo_cache())
    else:
        folder = args.shot if args.shot is not None else Path(project.shot)
    if not folder.exists():
        raise FileNotFoundError(f"shot {folder} does not exist")
    shot = load_shot(folder)
    if project is None:
        return shot, None, None
    return shot, project.edits, args.project.parent


def _demo(cache: Path) -> Path:
    """The demo shot (`x2video.demo.ensure_demo`), with a progress bar on stderr while Cycles renders it the first time."""
    from tqdm import tqdm

    from x2video.demo import STATED_TIME, ensure_demo

    bar = None

    def progress(done: int, total: int, seconds: float) -> None:
        nonlocal bar
        if bar is None:
            log.info("path-tracing the demo room with Cycles (%s) into %s", STATED_TIME, cache)
            bar = tqdm(total=total, desc="demo (Cycles)", unit="frame")
        bar.update(done - bar.n)

    try:
        folder = ensure_demo(cache, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    if bar is not None:
        from x2video.cycles.demo import describe

        log.info("demo shot %s: %s", folder, describe(folder))
    return folder


def _resume_key(args: argparse.Namespace, shot: Any, settings: RenderSettings, options: ModelOptions, fps: float) -> str:
    """What decides the frames of this render (`x2video.render.frames.resume_key`): a re-run with the same key takes
    over the frames a failed run staged; the shot's and the project's files are part of it, so a shot re-rendered
    meanwhile starts over."""
    from x2video import __version__
    from x2video.render.frames import files_identity, resume_key

    paths = [shot.info.source, args.project]
    inputs = [files_identity(p) for p in paths if p and Path(p).exists()]
    return resume_key(version=__version__, settings=dataclasses.asdict(settings), options=dataclasses.asdict(options), fps=fps,
                      inputs=[str(p) for p in paths], files=inputs, out=Path(args.out).name)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from x2video.base.plan import BASE, base_choice
    from x2video.render.frames import FrameSink
    from x2video.render.renderer import Renderer
    from x2video.sampling.planner import plan
    from x2video.tiers import registry as tiers
    from x2video.tiers.base import TIERS
    from x2video.weights import load_model, shipped_weights

    settings = from_args(RenderSettings, args)
    options = from_args(ModelOptions, args)
    shot, edits, base_dir = load_inputs(args)
    start, stop = settings.frames or (0, shot.num_frames)
    if not 0 <= start < stop <= shot.num_frames:
        raise ValueError(f"--frames: frame range [{start}, {stop}) outside the shot's {shot.num_frames} frames")
    units = OutputUnits.for_shot(shot, settings.exposure)
    log.info("%s: %s", args.out, units.describe())
    model = None
    # the formula needs no network and no weights; nor does a render of the shot's own path-traced frames with no edits
    if tiers.needs_model(settings.quality) and base_choice(shot, edits, settings) is None:
        plan(settings.scheme, stop - start, settings.window, max_levels=settings.max_levels)  # bad window sizes or levels fail before the model loads
        if options.untrained and options.weights is not None:
            raise ValueError("--untrained and --weights exclude each other")
        if not options.untrained and options.weights is None and shipped_weights() is None:
            from x2video.weights import HOW_TO_GET_WEIGHTS, where_weights_are_looked_for

            raise FileNotFoundError(HOW_TO_GET_WEIGHTS.format(where=where_weights_are_looked_for())
                                    + "; or pass --weights DIR, or add --untrained for a smoke render with random weights")
        model = load_model(**dataclasses.asdict(options))
    renderer = Renderer(model, retain=False)
    planned = renderer.plan_render(shot, edits, settings)
    steps_label = planned.tier if planned.per_frame else f"{planned.sampler}-{planned.steps}"
    t0 = time.perf_counter()
    bar = tqdm(unit="step", desc=f"render {steps_label}", dynamic_ncols=True)
    fps = args.fps if args.fps is not None else shot.info.fps
    with FrameSink(args.out, fps=fps, expected=list(range(start, stop)), units=units, resume=_resume_key(args, shot, settings, options, fps)) as sink:

        def on_event(event: RenderEvent) -> None:
            if isinstance(event, RenderStarted):
                if event.per_frame:  # tiers 0 and 1: one pass per frame
                    bar.unit, bar.desc = "frame", f"render {event.tier}"
                    bar.reset(total=event.num_frames)
                else:
                    bar.reset(total=event.num_windows * planned.steps)
                if event.reason:
                    log.info("tier %s: %s", event.tier, event.reason)
            elif isinstance(event, StepDone):
                bar.update(1)
            elif isinstance(event, FramesReady):
                if planned.per_frame:
                    bar.update(len(event.frames))
                bar.set_postfix(level=event.level, frames=len(event.frames))
            sink(event)

        try:  # a re-run after a failure (a full disk) resumes: a tier exact in part (the formula) renders only the frames
            # not kept, other tiers render again and write only those (a tier-1 batch of other frames may differ in the last bit)
            exact = planned.tier == BASE or TIERS[planned.tier].exact_in_part
            runs = sink.missing_runs() if sink.kept and exact else [(start, stop)]
            if sink.kept:
                log.info("%s: %d of %d frames kept from the last attempt", args.out, len(sink.kept), stop - start)
            for a, b in runs:
                renderer.render(shot, edits, dataclasses.replace(settings, frames=(a, b)), on_event=on_event, base_dir=base_dir)
            if sink.result is None:
                sink.finish()
        finally:
            bar.close()
    seconds = time.perf_counter() - t0
    n = stop - start
    print(f"wrote {n} frames to {args.out} in {seconds:.1f} s ({seconds / n:.2f} s/frame)")
    return 0
