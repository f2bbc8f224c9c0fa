"""`x2video eval`: render held-out shots with given weights and write results.json + results.md (paper-shaped tables a-d)."""
from __future__ import annotations

import argparse
import logging
import re
import shlex
import time
from pathlib import Path
from typing import Any

from x2video.cli.args import size_arg
from x2video.cli.fields import add_fields
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


def _step(path: Path) -> int | None:
    m = re.search(r"step-0*(\d+)", str(path))
    return int(m.group(1)) if m else None


def load_models(a: argparse.Namespace, *, with_image: bool = True) -> Any:
    """(EvalModels, video model folder or None) from the weights arguments; missing or broken weights fail
    with a clear message. `with_image=False` skips the image model (--untrained builds one otherwise)."""
    import torch

    from x2video.eval.runner import EvalModels
    from x2video.model.pipeline import X2VideoModel
    from x2video.train.runs import model_dir
    from x2video.weights import shipped_weights

    dev = a.device or ("cuda" if torch.cuda.is_available() else "cpu")
    dtype = torch.float16 if a.fp16 else torch.float32
    encoder_dtype = torch.bfloat16 if getattr(a, "bf16_encoder", False) else None
    channel_encoder = getattr(a, "channel_encoder", DEFAULT_CHANNEL_ENCODER)
    if a.untrained:
        if a.weights or a.image_weights or a.lcm_weights:
            raise ValueError("--untrained excludes --weights, --image-weights and --lcm-weights")
        video = X2VideoModel.untrained("tiny", device=dev, dtype=dtype)
        image = X2VideoModel.untrained("tiny", seed=1, device=dev, dtype=dtype, video=False) if with_image else None
        info = {r: {"path": "untrained", "untrained": True, "config": "tiny", "video": r == "video"} for r in ("video", "image")}
        return EvalModels(video, image, None, info), None

    weights = a.weights
    if weights is None:
        weights = shipped_weights()
        if weights is None:
            raise FileNotFoundError("no --weights given and no shipped weights found (a folder with config.json and "
                                    "unet.safetensors); pass --weights RUN_OR_DIR, or --untrained for a smoke test")

    def load(path: Path, role: str, want_video: bool, want_lcm: bool = False) -> tuple[Any, dict, Path]:
        if not path.exists():
            raise FileNotFoundError(f"--{role}: {path} does not exist")
        d = model_dir(path)
        for part in ("unet.safetensors", "vae.safetensors"):
            if not (d / part).is_file():
                raise FileNotFoundError(f"--{role}: {d} has no {part}")
        # The image model of table (a) is compared with the video model as the paper's baseline: it encodes its channels
        # like the video model where it can ("distilled" needs its own channel_encoder.safetensors, so "auto" for it).
        enc = "auto" if role == "image-weights" and channel_encoder == "distilled" else channel_encoder
        model = X2VideoModel.from_pretrained(d, device=dev, dtype=dtype, encoder_dtype=encoder_dtype, channel_encoder=enc)
        if model.config.video != want_video:
            kind = "video" if model.config.video else "image"
            raise ValueError(f"--{role}: {d} holds an {kind} model; expected {'a video' if want_video else 'an image'} model")
        if want_lcm and not model.has_lcm:
            raise ValueError(f"--{role}: {d} has no lcm_unet.safetensors (distil one with `x2video train lcm`)")
        info = {"path": str(d), "config": model.config.name, "video": model.config.video, "shading_prior": model.config.shading_prior,
                "lcm": model.has_lcm, "step": _step(d), "untrained": False}
        if encoder_dtype is not None:
            info["encoder_dtype"] = str(encoder_dtype).removeprefix("torch.")
        info["channel_encoder"] = "vae" if model.channel_encoder is None else "distilled"
        return model, info, d

    video, vinfo, vdir = load(weights, "weights", True)
    info = {"video": vinfo}
    image = lcm = None
    if a.image_weights is not None and with_image:
        image, info["image"], _ = load(a.image_weights, "image-weights", False)
    if a.lcm_weights is not None:
        lcm, info["lcm"], _ = load(a.lcm_weights, "lcm-weights", True, want_lcm=True)
        if info["lcm"]["channel_encoder"] != vinfo["channel_encoder"]:  # table (d) compares samplers, not encoders
            raise ValueError(f"--channel-encoder {channel_encoder}: --weights encodes the channels with its "
                             f"{vinfo['channel_encoder']} encoder, --lcm-weights with its {info['lcm']['channel_encoder']} one; "
                             "pick vae or distilled explicitly")
    elif video.has_lcm:
        info["lcm"] = dict(vinfo, note="lcm_unet.safetensors of --weights")
    return EvalModels(video, image, lcm, info), vdir


def resolve_size(a: argparse.Namespace, weights_dir: Path | None, downsample: int) -> tuple[tuple[int, int], str]:
    """(W, H) to evaluate at and a sentence saying why."""
    from x2video.eval.data import native_size, training_size

    native = native_size(a.data, a.split)
    if a.size is not None:
        size, why = tuple(a.size), f"--size {a.size[0]}x{a.size[1]}"
    else:
        trained = training_size(weights_dir) if weights_dir is not None else None
        if trained is not None and trained[0] * trained[1] < native[0] * native[1]:
            size, why = trained, f"the model was trained at {trained[0]}x{trained[1]}"
        elif trained is not None:
            size, why = native, f"the data's size (model trained at {trained[0]}x{trained[1]})"
        else:
            size, why = native, "the data's size (the weights do not record a training size)"
    if size[0] % downsample or size[1] % downsample:
        raise ValueError(f"evaluation size {size[0]}x{size[1]} ({why}) is not a multiple of the model's VAE factor {downsample}; pass --size")
    if tuple(size) != tuple(native):
        why += f"; ground truth, channels and motion area-downsampled from {native[0]}x{native[1]}"
        if abs(size[0] / size[1] - native[0] / native[1]) > 0.02:
            why += f" (aspect ratio {native[0] / native[1]:.3f} -> {size[0] / size[1]:.3f}: images are stretched)"
            log.warning("evaluation size %dx%d stretches the data's %dx%d frames", size[0], size[1], native[0], native[1])
    return tuple(size), why  # type: ignore[return-value]


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
