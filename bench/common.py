"""What the benches share: result folders, the JSON header every result starts with, and the data, weights
and sampling flags (generated from `RenderSettings` and `ModelOptions`, as `x2video render` does)."""
from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from pathlib import Path
from typing import Any, Callable

from x2video.cli.args import size_arg
from x2video.fields import add_fields, from_args
from x2video.render.settings import RenderSettings
from x2video.weights import ModelOptions

#: bench/results/: one folder per bench, repository-relative paths inside the JSONs
RESULTS = Path(__file__).resolve().parent / "results"
#: the sampling flags the accuracy benches take (the rest of RenderSettings is each bench's business)
SAMPLING_FIELDS = ("seed", "window", "replace_refs", "seams", "max_levels", "noise", "noise_shared", "ref_dc", "resample")


def clean_json(x: Any, digits: int = 5) -> Any:
    """`x` made fit for a results JSON: floats rounded to `digits`, non-finite ones None, keys as strings, tuples as lists."""
    if isinstance(x, float):
        return None if not math.isfinite(x) else round(x, digits)
    if isinstance(x, dict):
        return {str(k): clean_json(v, digits) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean_json(v, digits) for v in x]
    return x


def results_path(bench: str, name: str | None = None, suffix: str = ".json") -> Path:
    """bench/results/BENCH/NAME.json (NAME defaults to the bench's name)."""
    return RESULTS / bench / f"{name or bench}{suffix}"


def command(bench: str, argv: list[str] | None = None) -> str:
    """The command that reproduces a result: `python -m bench.BENCH ARGS`, machine paths replaced by placeholders."""
    from x2video.io.paths import scrub_paths

    return scrub_paths(shlex.join(["python", "-m", f"bench.{bench}", *(sys.argv[1:] if argv is None else argv)]))


def result_header(kind: str, bench: str, args: argparse.Namespace, models: Any, shots: list, size: tuple[int, int],
                  argv: list[str] | None = None) -> dict:
    """The fields every accuracy bench's JSON starts with: format, the command that reproduces it, machine,
    weights, data (paths repository-relative or placeholders)."""
    from x2video.eval.machine import machine_info
    from x2video.io.paths import portable_path

    return {
        "format": f"x2video-{kind}",
        "command": command(bench, argv),
        "machine": machine_info(models.video.device),
        "weights": models.info,
        "data": {"dir": portable_path(args.data), "split": args.split, "rooms": [s.name for s in shots], "frames": args.frames,
                 "size": list(size)},
    }


def add_render_arguments(p: argparse.ArgumentParser) -> None:
    """Held-out data, weights, device and sampling flags of the accuracy benches."""
    p.add_argument("--data", type=Path, required=True, help="data set folder (DATA/test/room_*)")
    p.add_argument("--split", default="test")
    p.add_argument("--rooms", type=int, default=2, help="first K held-out rooms (default 2)")
    p.add_argument("--frames", type=int, default=17, help="first T frames per shot (default 17)")
    p.add_argument("--size", type=size_arg, help="WxH (default: the model's training size)")
    p.add_argument("--lcm-weights", type=Path, help="LCM run or folder")
    add_fields(p.add_argument_group("model"), ModelOptions, skip=("untrained",))
    add_fields(p.add_argument_group("sampling"), RenderSettings, only=SAMPLING_FIELDS)
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = default)")


def load_models(args: argparse.Namespace, *, with_image: bool = False) -> tuple[Any, Any, tuple[int, int], str]:
    """(EvalModels, video weights folder, evaluation size, why that size) from the flags above."""
    from x2video.eval.loading import load_eval_models, resolve_size

    models, weights_dir = load_eval_models(args.weights, getattr(args, "image_weights", None), args.lcm_weights,
                                           options=from_args(ModelOptions, args, weights=None), with_image=with_image)
    size, why = resolve_size(args.data, args.split, args.size, weights_dir, models.video.downsample)
    return models, weights_dir, size, why


def settings(args: argparse.Namespace, **overrides: Any) -> RenderSettings:
    """The RenderSettings the sampling flags give, with `overrides`; base 'off' unless overridden: the accuracy benches
    score the tiers against the shot's own rgb, which a render over the base would return."""
    return from_args(RenderSettings, args, **{"base": "off", **overrides})


def run_measure(args: argparse.Namespace, measure_fn: Callable[[argparse.Namespace], dict]) -> dict:
    """Set torch's threads, run `measure_fn(args)`, add its wall time and write the JSON to args.out atomically."""
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    from x2video.io.atomic import write_json_atomic

    t0 = time.perf_counter()
    result = measure_fn(args)
    result["wall_seconds"] = time.perf_counter() - t0
    write_json_atomic(args.out, result)
    return result
