"""`x2video eval`: render held-out shots with given weights and write results.json + results.md (paper-shaped tables a-d)."""
from __future__ import annotations

import argparse
import logging
import shlex
import time
from pathlib import Path
from typing import Any

from x2video.cli.args import size_arg
from x2video.fields import add_fields, from_args
from x2video.model.config import DEFAULT_CHANNEL_ENCODER
from x2video.weights import ModelOptions

log = logging.getLogger(__name__)


def _choices(allowed: tuple[str, ...]):
    """argparse type: a comma-separated, non-empty subset of `allowed`."""

    def parse(text: str) -> tuple[str, ...]:
        picked = tuple(v.strip() for v in text.split(",") if v.strip())
        if not picked or any(v not in allowed for v in picked):
            raise argparse.ArgumentTypeError(f"{text!r}: choose from {','.join(allowed)}")
        return picked

    return parse


def _conditions(text: str) -> tuple[str, ...]:
    """argparse type: comma-separated KIND[+text][+ref] conditions (`x2video.eval.conditions.parse_condition`)."""
    from x2video.eval.conditions import parse_condition

    picked = tuple(v.strip() for v in text.split(",") if v.strip())
    if not picked:
        raise argparse.ArgumentTypeError(f"{text!r}: no condition given")
    try:
        return tuple(parse_condition(v).token for v in picked)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from e


def register(subparsers: argparse._SubParsersAction) -> None:
    from x2video.eval.conditions import KINDS
    from x2video.eval.config import TABLES, EvalConfig

    d = EvalConfig()
    p = subparsers.add_parser(
        "eval",
        help="measure a model on held-out rooms: paper-shaped tables (image vs video, controls, sampling, LCM)",
        description="Render the held-out shots of DATA with the given weights and write RESULTS_DIR/results.json and "
                    "results.md: (a) image model per frame vs video model, (b) full channels vs Mask A|M|R vs Drop "
                    "irradiance (+ Text, + Ref.), (c) recursive vs sequential on long shots, (d) DDIM vs LCM. Every row "
                    "also scores the classical shading of the same channels. Model card: python -m x2video.eval.card.",
    )
    g = p.add_argument_group("weights")
    g.add_argument("--weights", type=Path, help="video model: a training run (newest step-*/model) or a model folder "
                                                "(default: the shipped weights)")
    g.add_argument("--image-weights", type=Path, help="image-stage run or model folder for table (a)'s per-frame row")
    g.add_argument("--lcm-weights", type=Path, help="LCM run or model folder (with lcm_unet.safetensors) for table (d)")
    g.add_argument("--untrained", action="store_true", help="untrained tiny video + image models (smoke test: numbers mean nothing)")
    add_fields(g, ModelOptions, only=("device", "fp16", "bf16_encoder", "channel_encoder"))
    g = p.add_argument_group("data")
    g.add_argument("--data", type=Path, required=True, help="data set folder from `x2video dataset make` (DATA/test/room_*)")
    add_fields(g, EvalConfig, only=("split", "rooms"))
    g.add_argument("--frames", type=int, default=d.frames, help=f"first T frames per shot for tables a, b, d (default {d.frames}; 0 = all)")
    g.add_argument("--long-data", type=Path, help="data set with long shots for table (c) (make it with --frames 65; default: --data)")
    add_fields(g, EvalConfig, only=("long_frames",))
    g.add_argument("--long-conditions", type=_conditions, default=d.long_conditions,
                   help="conditions table (c) compares recursive and sequential under: comma-separated KIND[+text][+ref], "
                   f"KIND one of {', '.join(KINDS)}; +ref gives the ground-truth frame 0 as reference, which sequential "
                   f"sampling passes along window by window (default {','.join(d.long_conditions)})")
    g.add_argument("--size", type=size_arg, help="evaluate at WxH (default: the model's training size when recorded, else the data's)")
    g = p.add_argument_group("what to measure")
    g.add_argument("--tables", type=_choices(TABLES), default=d.tables, help="comma-separated subset of a,b,c,d (default all)")
    add_fields(g, EvalConfig, only=("steps", "lcm_steps", "seed", "window", "masks", "replace_refs", "seams", "max_levels", "ref_dc",
                                   "resample", "noise", "noise_shared"))
    g.add_argument("--no-fid", action="store_true", help="skip FID (Inception features of every frame)")
    g.add_argument("--no-tc", action="store_true", help="skip temporal consistency")
    g.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = torch's default)")
    g = p.add_argument_group("output")
    g.add_argument("--out", type=Path, required=True, help="results folder (results.json, results.md)")
    g.add_argument("--renders", type=int, default=0, help="write ground truth | image model | video model contact sheets "
                                                          "and MP4s of the first N shots (needs table a)")
    g.add_argument("--renders-out", type=Path, help="folder for --renders (default RESULTS_DIR/renders; docs/renders for the card)")
    p.set_defaults(func=run)


def command_line(a: argparse.Namespace) -> str:
    """The canonical `x2video eval ...` command reproducing these results, every setting explicit."""
    parts = ["x2video", "eval"]
    if a.untrained:
        parts.append("--untrained")
    for flag, v in (("--weights", a.weights), ("--image-weights", a.image_weights), ("--lcm-weights", a.lcm_weights),
                    ("--data", a.data), ("--long-data", a.long_data)):
        if v is not None:
            parts += [flag, str(v)]
    parts += ["--split", a.split]
    if a.rooms is not None:
        parts += ["--rooms", str(a.rooms)]
    parts += ["--frames", str(a.frames), "--long-frames", str(a.long_frames)]
    if "c" in a.tables:
        parts += ["--long-conditions", ",".join(a.long_conditions)]
    parts += ["--tables", ",".join(a.tables)]
    if a.size is not None:
        parts += ["--size", f"{a.size[0]}x{a.size[1]}"]
    parts += ["--steps", str(a.steps), "--lcm-steps", str(a.lcm_steps), "--seed", str(a.seed), "--window", str(a.window),
              "--masks", str(a.masks)]
    parts.append("--replace-refs" if a.replace_refs else "--no-replace-refs")  # explicit: the default changed once
    parts.append("--seams" if a.seams else "--no-seams")
    if a.max_levels is not None:
        parts += ["--max-levels", str(a.max_levels)]
    parts += ["--ref-dc", f"{getattr(a, 'ref_dc', 0.0):g}"]  # explicit: it changes every recursive row
    if getattr(a, "resample", 1) != 1:
        parts += ["--resample", str(a.resample)]
    parts += ["--noise", a.noise] + (["--noise-shared", f"{a.noise_shared:g}"] if a.noise == "frame" else [])
    parts += ["--channel-encoder", getattr(a, "channel_encoder", DEFAULT_CHANNEL_ENCODER)]  # explicit: the timings depend on it
    for flag, on in (("--no-fid", a.no_fid), ("--no-tc", a.no_tc), ("--fp16", a.fp16), ("--bf16-encoder", getattr(a, "bf16_encoder", False))):
        if on:
            parts.append(flag)
    if a.device:
        parts += ["--device", a.device]
    if a.threads:  # seconds per frame depend on it (the UNet and the VAE scale differently with threads)
        parts += ["--threads", str(a.threads)]
    parts += ["--out", str(a.out)]
    return shlex.join(parts)


def load_models(a: argparse.Namespace, *, with_image: bool = True) -> Any:
    """(EvalModels, video model folder or None) from the weights flags (`x2video.eval.loading.load_eval_models`)."""
    from x2video.eval.loading import load_eval_models

    return load_eval_models(a.weights, getattr(a, "image_weights", None), getattr(a, "lcm_weights", None),
                            options=from_args(ModelOptions, a, weights=None), with_image=with_image)


def resolve_size(a: argparse.Namespace, weights_dir: Path | None, downsample: int) -> tuple[tuple[int, int], str]:
    """(W, H) to evaluate at and a sentence saying why (`x2video.eval.loading.resolve_size`)."""
    from x2video.eval.loading import resolve_size as resolve

    return resolve(a.data, a.split, a.size, weights_dir, downsample)


def run(a: argparse.Namespace) -> int:
    from tqdm import tqdm

    from x2video.eval.config import EvalConfig
    from x2video.eval.data import load_eval_shots
    from x2video.eval.report import results_markdown
    from x2video.eval.runner import EvalProgress, evaluate, with_models_info
    from x2video.io.atomic import write_json_atomic, write_text_atomic

    if a.threads:
        import torch

        torch.set_num_threads(a.threads)
    frames = None if a.frames == 0 else a.frames
    config = EvalConfig(tables=a.tables, split=a.split, rooms=a.rooms, frames=frames, long_frames=a.long_frames, long_conditions=a.long_conditions, size=a.size,
                        steps=a.steps, lcm_steps=a.lcm_steps, seed=a.seed, window=a.window, masks=a.masks, fid=not a.no_fid,
                        tc=not a.no_tc, replace_refs=a.replace_refs, seams=a.seams, max_levels=a.max_levels, noise=a.noise, noise_shared=a.noise_shared,
                        resample=a.resample, ref_dc=a.ref_dc)
    if a.renders and "a" not in config.tables:
        raise ValueError("--renders uses table (a)'s renders; add a to --tables")
    for flag, path in (("--data", a.data), ("--long-data", a.long_data)):
        if path is not None and not path.is_dir():
            raise FileNotFoundError(f"{flag}: data set folder {path} does not exist")
    models, weights_dir = load_models(a, with_image='a' in config.tables)
    size, size_note = resolve_size(a, weights_dir, models.video.downsample)
    config.size = size
    data = {"main": load_eval_shots(a.data, a.split, a.rooms, frames, size)}
    described = {"main": (a.data, frames)}
    if "c" in config.tables:
        long_dir = a.long_data or a.data
        data["long"] = load_eval_shots(long_dir, a.split, a.rooms, a.long_frames, size)
        described["long"] = (long_dir, a.long_frames)

    captured: dict[str, dict[str, list]] = {}

    def keep(spec, shot, frames_) -> None:
        if a.renders and spec.table == "a" and shot.name in [s.name for s in data["main"][: a.renders]]:
            captured.setdefault(shot.name, {})[spec.model] = frames_

    bar = tqdm(desc="eval", unit="render", dynamic_ncols=True)

    def progress(p: EvalProgress) -> None:
        bar.total = p.total
        bar.n = p.done
        bar.set_postfix_str(f"({p.table}) {p.label}" + (f" / {p.shot}" if p.shot else ""), refresh=True)

    t0 = time.perf_counter()
    try:
        results = evaluate(models, data, config, on_progress=progress, on_frames=keep)
    finally:
        bar.close()
    results = with_models_info(results, models)
    results["command"] = command_line(a)
    results["data"] = {
        k: {"dir": str(d), "split": a.split, "rooms": [s.name for s in data[k]], "frames": sorted({s.num_frames for s in data[k]}),
            "size": list(size), "size_note": size_note,
            "description": f"{len(data[k])} {a.split} room(s) of {d} ({', '.join(s.name for s in data[k][:6])}"
                           f"{', ...' if len(data[k]) > 6 else ''}), {'/'.join(str(n) for n in sorted({s.num_frames for s in data[k]}))} "
                           f"frames at {size[0]}x{size[1]}: {size_note}"}
        for k, (d, _) in described.items()
    }
    results["wall_seconds_total"] = time.perf_counter() - t0
    a.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(a.out / "results.json", results)
    write_text_atomic(a.out / "results.md", results_markdown(results))
    if a.renders:
        from x2video.eval.contact import write_comparison

        out = a.renders_out or a.out / "renders"
        for s in data["main"][: a.renders]:
            got = captured.get(s.name, {})
            sources = [("ground truth", s.gt)]
            sources += [(label, got[role]) for role, label in (("image", "image model (per frame)"), ("video", "video model")) if role in got]
            png, mp4 = write_comparison(out, s.name, sources, fps=s.shot.info.fps)
            print(f"wrote {png} and {mp4}")
    print(f"wrote {a.out / 'results.json'} and {a.out / 'results.md'} in {results['wall_seconds_total']:.0f} s")
    return 0
