"""`x2video farm`: render many shots on a Ray cluster (or write Open Job Description templates for them)."""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from x2video.fields import add_fields, from_args
from x2video.render.settings import RenderSettings
from x2video.weights import ModelOptions

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "farm",
        help="render many shots on a Ray cluster, resumable (docs/FARM.md)",
        description="Render every shot in SOURCES (shot folders, project files, folders of them, or list files with one path a line) "
                    "into the shared folder OUT, one Ray task per shot. Finished shots (output + OUT/NAME.done.json) are skipped, "
                    "so the same command resumes a stopped farm. docs/FARM.md says how to start a cluster.",
    )
    p.add_argument("sources", nargs="*", type=Path, metavar="SOURCES", help="shots, projects (*.x2v.json), folders of them, or list files")
    p.add_argument("--out", type=Path, required=True, help="shared output folder: OUT/NAME/ (EXR frames) or OUT/NAME.mp4 per shot")
    p.add_argument("--format", choices=("exr", "mp4"), default="exr", help="EXR frame folders (linear, the input's units) or MP4 (default: exr)")
    p.add_argument("--fps", type=float, help="MP4 frame rate (default: each shot's)")
    p.add_argument("--address", help="Ray cluster to use: 'auto' (the one `ray start` began on this machine) or HOST:PORT "
                                     "(default: $RAY_ADDRESS, else a local cluster for this run)")
    p.add_argument("--local-cpus", type=int, help="CPUs of the local cluster started when there is no --address (default: all)")
    p.add_argument("--cpus-per-shot", type=float, default=1, help="CPUs each shot's task asks for, also torch's threads (default: 1)")
    p.add_argument("--chunk-frames", type=int, default=None, metavar="N",
                   help="frames per task for shots rendered frame by frame (tiers 0 and 1: the formula, the residual net; "
                        "what quality auto renders for a shot with every channel) (default: 64)")
    p.add_argument("--no-split", dest="split", action="store_false",
                   help="render each shot as one task (default: frame chunks for tiers 0 and 1, one task per window for diffusion)")
    p.add_argument("--retries", type=int, default=3, help="times a shot is started again when its worker dies (default: 3)")
    p.add_argument("--redo", action="store_true", help="render finished shots again (default: skip them)")
    p.add_argument("--openjd", type=Path, metavar="DIR", help="write an Open Job Description template per shot into DIR and stop (no Ray)")
    p.add_argument("--status", action="store_true", help="print the state of every shot in OUT (from another terminal) and stop")
    add_fields(p.add_argument_group("sampling (x2video.RenderSettings)"), RenderSettings)
    add_fields(p.add_argument_group("model (x2video.weights.ModelOptions)"), ModelOptions)
    p.set_defaults(func=run)


def print_status(out: Path) -> int:
    """One line per shot with a status file or a done marker in `out`; 1 when any failed."""
    from x2video.farm import state

    names = sorted({p.name[: -len(".status.json")] for p in (out / ".farm").glob("*.status.json")}
                   | {p.name[: -len(".done.json")] for p in out.glob("*.done.json")})
    if not names:
        print(f"{out}: no farm shots here")
        return 0
    failed = 0
    for name in names:
        marker = state.read_json(state.marker_path(out, name))
        s = state.read_status(out, name)
        if marker is not None:
            print(f"{name}: done, {marker.get('frames')} frames in {marker.get('seconds')} s on {marker.get('host')} ({marker.get('finished')})")
            continue
        failed += s.get("state") == "failed"
        where = (f"{s.get('parts_kind')} {s.get('parts_done')}/{s.get('parts_total')} done, {s.get('parts_running')} running, attempt {s.get('attempt')}"
                 if s.get("parts_total") else f"attempt {s.get('attempt')} on {s.get('host')}:{s.get('pid')}")
        print(f"{name}: {s.get('state')}, {s.get('frames_done', 0)}/{s.get('frames_total') or '?'} frames, {where}"
              + (f": {s['error']}" if s.get("error") else ""))
    return 1 if failed else 0


def run(args: argparse.Namespace) -> int:
    from x2video.farm import find_jobs, run_farm
    from x2video.farm.chunks import CHUNK_FRAMES

    if args.status:
        return print_status(args.out)
    if not args.sources:
        raise ValueError("nothing to render: give shot folders, project files, folders of them or list files")
    settings = from_args(RenderSettings, args)
    options = from_args(ModelOptions, args)
    jobs = find_jobs(args.sources)
    if args.openjd is not None:
        from x2video.farm.openjd import write_templates

        paths = write_templates(jobs, args.openjd, args.out, settings, options, args.format, args.fps)
        print(f"wrote {len(paths)} Open Job Description template(s) to {args.openjd} "
              f" (run one here: openjd run {paths[0]} -p file://{paths[0].with_name(paths[0].name.replace('.template.', '.params.'))})")
        return 0
    from x2video.tiers.registry import needs_model

    if needs_model(settings.quality) and not options.untrained and options.weights is None:
        from x2video.weights import HOW_TO_GET_WEIGHTS, shipped_weights, where_weights_are_looked_for

        if shipped_weights() is None:
            raise FileNotFoundError(HOW_TO_GET_WEIGHTS.format(where=where_weights_are_looked_for()) + "; or pass --weights DIR")
    result = run_farm(jobs, args.out, settings, options, fmt=args.format, fps=args.fps, address=args.address, local_cpus=args.local_cpus,
                      cpus_per_shot=args.cpus_per_shot, retries=args.retries,
                      chunk_frames=args.chunk_frames or CHUNK_FRAMES, split=args.split, redo=args.redo, write=lambda s: print(s, flush=True))
    print(f"farm: {len(result.done)} rendered, {len(result.skipped)} finished before, {len(result.failed)} failed, {result.seconds:.1f} s")
    for name, error in result.failed.items():
        print(f"farm {name}: {error}", file=sys.stderr)
    return 0 if result.ok else 1
