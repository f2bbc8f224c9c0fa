"""`x2video render`: render a shot (optionally with a project's edits) to an MP4 or an EXR folder."""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import Any

from x2video.cli.args import BF16_ENCODER_HELP, CHANNEL_ENCODER_HELP, MAX_LEVELS_HELP, NOISE_HELP, NOISE_SHARED_HELP, REF_DC_HELP, RESAMPLE_HELP, SEAMS_HELP
from x2video.io.units import OutputUnits
from x2video.model.config import CHANNEL_ENCODERS, DEFAULT_CHANNEL_ENCODER
from x2video.sampling.events import (
    FramesReady,
    RenderEvent,
    RenderSettings,
    RenderStarted,
    StepDone,
)

log = logging.getLogger(__name__)

#: repository resources/ (shipped weights live in a sub-folder holding config.json + unet.safetensors)
RESOURCES = Path(__file__).resolve().parents[3] / "resources"
DEMO_CACHE = Path("~/.cache/x2video/demo").expanduser()


def register(subparsers: argparse._SubParsersAction) -> None:
    d = RenderSettings()
    p = subparsers.add_parser(
        "render",
        help="render a shot to video with the X2Video model",
        description="Render SHOT (a shot folder, or --demo) to OUT: a .mp4 file or a folder of EXR frames.",
    )
    p.add_argument("shot", nargs="?", type=Path, help="shot folder (or any layout `x2video info` reads)")
    p.add_argument("--demo", action="store_true", help="render the bundled procedural demo shot (generated on first use)")
    p.add_argument("--demo-dir", type=Path, default=DEMO_CACHE, help=f"where the demo shot is cached (default {DEMO_CACHE})")
    p.add_argument("--project", type=Path, help="project file with edits, masks, prompts and reference frame (its shot is used when SHOT is not given)")
    p.add_argument("--out", type=Path, required=True, help="output: OUT.mp4 (H.264, sRGB) or a folder of linear EXR frames")
    p.add_argument("--quality", choices=["formula", "diffusion"], default=d.quality,
                   help="diffusion (default): the model; formula: no network, albedo x irradiance (+ GGX where "
                        "roughness and normals are given), exact for diffuse light, any frame size, no weights needed")
    p.add_argument("--exposure", type=_exposure, default=d.exposure,
                   help="MP4 exposure in stops on the input's units, or 'auto' (default): the shot's own irradiance "
                        "normalisation (stated in the log). EXR output is always in the input's units")
    p.add_argument("--preset", choices=["fast", "quality"], help="fast = LCM-2 with distilled weights, else DDIM-4; quality = DDIM-20")
    p.add_argument("--sampler", choices=["ddim", "lcm"], default=d.sampler, help="sampler (ignored with --preset)")
    p.add_argument("--steps", type=int, default=d.steps, help=f"denoising steps per window (default {d.steps}; ignored with --preset)")
    p.add_argument("--seed", type=int, default=d.seed, help="seed of the initial noise")
    p.add_argument("--scheme", choices=["recursive", "sequential"], default=d.scheme, help="frame schedule")
    p.add_argument("--window", type=int, default=d.window, help=f"frames per window N (default {d.window})")
    p.add_argument("--frames", type=_frame_range, help="render only frames START:STOP of the shot")
    p.add_argument("--no-detail", dest="detail", action="store_false",
                   help="residual models: do not add back the classical shading's fine detail the VAE loses (an ablation)")
    p.add_argument("--replace-refs", action=argparse.BooleanOptionalAction, default=d.replace_refs,
                   help="hold each window's reference frames at their noised latents between denoising steps, as in "
                        "training (default on; --no-replace-refs lets each window re-estimate them)")
    p.add_argument("--seams", action=argparse.BooleanOptionalAction, default=d.seams, help=SEAMS_HELP)
    p.add_argument("--max-levels", type=int, default=d.max_levels, help=MAX_LEVELS_HELP)
    p.add_argument("--ref-dc", type=float, default=d.ref_dc, help=REF_DC_HELP + f" (default {d.ref_dc:g})")
    p.add_argument("--resample", type=int, default=d.resample, help=RESAMPLE_HELP)
    p.add_argument("--noise", choices=("window", "frame"), default=d.noise, help=NOISE_HELP + f" (default {d.noise})")
    p.add_argument("--noise-shared", type=float, default=d.noise_shared, help=NOISE_SHARED_HELP + f" (default {d.noise_shared})")
    p.add_argument("--weights", type=Path, help="model checkpoint folder (default: the weights shipped in resources/)")
    p.add_argument("--untrained", action="store_true", help="use untrained tiny weights (smoke test: the output is noise)")
    p.add_argument("--device", default=None, help="torch device (default: cuda when available, else cpu)")
    p.add_argument("--fp16", action="store_true", help="half precision (GPU)")
    p.add_argument("--bf16-encoder", action="store_true", help=BF16_ENCODER_HELP)
    p.add_argument("--channel-encoder", choices=CHANNEL_ENCODERS, default=DEFAULT_CHANNEL_ENCODER, help=CHANNEL_ENCODER_HELP)
    p.add_argument("--fps", type=float, help="MP4 frame rate (default: the shot's)")
    p.set_defaults(func=run)


def _exposure(text: str) -> float | str:
    from x2video.io.units import parse_exposure

    try:
        return parse_exposure(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--exposure: {exc}") from None


def _frame_range(text: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--frames wants START:STOP, got {text!r}") from None
    return a, b


def shipped_weights(resources: Path | None = None) -> Path | None:
    """The first folder under resources/ holding a model checkpoint (config.json + unet.safetensors)."""
    resources = RESOURCES if resources is None else resources
    if not resources.is_dir():
        return None
    found = sorted(p.parent for p in resources.glob("*/config.json") if (p.parent / "unet.safetensors").is_file())
    return found[0] if found else None


def load_model(weights: Path | None, untrained: bool, device: str | None, fp16: bool, bf16_encoder: bool = False,
               channel_encoder: str = DEFAULT_CHANNEL_ENCODER) -> Any:
    import torch

    from x2video.model.pipeline import X2VideoModel

    dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
    dtype = torch.float16 if fp16 else torch.float32
    encoder_dtype = torch.bfloat16 if bf16_encoder else None
    if untrained:
        if weights is not None:
            raise ValueError("--untrained and --weights exclude each other")
        return X2VideoModel.untrained("tiny", device=dev, dtype=dtype)  # test weights: --bf16-encoder does not apply
    if weights is None:
        weights = shipped_weights()
        if weights is None:
            raise FileNotFoundError(
                f"no trained weights in {RESOURCES} (a folder with config.json and unet.safetensors). "
                "Train them with `x2video train ...` (see README), pass --weights DIR, "
                "or add --untrained for a smoke render with random weights"
            )
    if not (weights / "config.json").is_file():
        raise FileNotFoundError(f"{weights} is not a model checkpoint folder (no config.json)")
    return X2VideoModel.from_pretrained(weights, device=dev, dtype=dtype, encoder_dtype=encoder_dtype, channel_encoder=channel_encoder)


def ensure_demo(cache: Path) -> Path:
    """The demo shot (`x2video dataset demo`'s recipe) under `cache`, generated on first use."""
    from x2video.cli.dataset import DEMO

    folder = cache / f"seed{DEMO['seed']}-{DEMO['frames']}f-{DEMO['width']}x{DEMO['height']}"
    if not (folder / "shot.json").is_file():
        from x2video.procedural.shotgen import write_procedural_shot

        log.info("generating the demo shot in %s (once)", folder)
        folder.parent.mkdir(parents=True, exist_ok=True)
        write_procedural_shot(folder, DEMO["seed"], DEMO["frames"], DEMO["width"], DEMO["height"], overwrite=True)
    return folder


def load_inputs(args: argparse.Namespace) -> tuple[Any, Any, Path | None]:
    """(shot, edits or None, folder that relative paths in the project refer to).

    The shot is SHOT, the demo shot (--demo), or the shot the --project file names.
    """
    from x2video.io.shotdir import load_shot

    project = None
    if args.project is not None:
        from x2video.edits import load_project

        project = load_project(args.project)
    sources = [s for s in (args.shot, args.demo or None, project) if s is not None]
    if args.shot is not None and args.demo:
        raise ValueError("give either a SHOT folder or --demo, not both")
    if not sources:
        raise ValueError("nothing to render: give a SHOT folder, --demo, or a --project file")
    if args.demo:
        folder = ensure_demo(args.demo_dir)
    elif args.shot is not None:
        folder = args.shot
    else:
        folder = Path(project.shot)
    if not folder.exists():
        raise FileNotFoundError(f"shot {folder} does not exist")
    shot = load_shot(folder)
    if project is None:
        return shot, None, None
    return shot, project.edits, args.project.parent


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from x2video.sampling.planner import plan
    from x2video.sampling.renderer import Renderer, select_steps
    from x2video.sampling.sink import FrameSink

    settings = RenderSettings(
        sampler=args.sampler,
        steps=args.steps,
        seed=args.seed,
        window=args.window,
        scheme=args.scheme,
        frames=args.frames,
        preset=args.preset,
        detail=args.detail,
        replace_refs=args.replace_refs,
        seams=args.seams,
        resample=args.resample,
        ref_dc=args.ref_dc,
        max_levels=args.max_levels,
        noise=args.noise,
        noise_shared=args.noise_shared,
        quality=args.quality,
        exposure=args.exposure,
    )
    shot, edits, base_dir = load_inputs(args)
    start, stop = settings.frames or (0, shot.num_frames)
    if not 0 <= start < stop <= shot.num_frames:
        raise ValueError(f"--frames: frame range [{start}, {stop}) outside the shot's {shot.num_frames} frames")
    units = OutputUnits.for_shot(shot, settings.exposure)
    log.info("%s: %s", args.out, units.describe())
    if settings.quality == "formula":
        from x2video.sampling.formula import formula_frames

        render, steps_label, steps = formula_frames, "formula", 1
    else:
        plan(settings.scheme, stop - start, settings.window, max_levels=settings.max_levels)  # bad window sizes or levels fail before the model loads
        model = load_model(args.weights, args.untrained, args.device, args.fp16, args.bf16_encoder, args.channel_encoder)
        resolved = select_steps(settings, model)
        render, steps_label, steps = Renderer(model).render, f"{resolved.sampler}-{resolved.steps}", resolved.steps
    t0 = time.perf_counter()
    bar = tqdm(unit="step", desc=f"render {steps_label}", dynamic_ncols=True)
    with FrameSink(args.out, fps=args.fps or shot.info.fps, expected=list(range(start, stop)), units=units) as sink:

        def on_event(event: RenderEvent) -> None:
            if isinstance(event, RenderStarted):
                bar.reset(total=event.num_windows * steps)
            elif isinstance(event, StepDone):
                bar.update(1)
            elif isinstance(event, FramesReady):
                bar.set_postfix(level=event.level, frames=len(event.frames))
            sink(event)

        try:
            render(shot, edits, settings, on_event=on_event, base_dir=base_dir)
        finally:
            bar.close()
    seconds = time.perf_counter() - t0
    n = stop - start
    print(f"wrote {n} frames to {args.out} in {seconds:.1f} s ({seconds / n:.2f} s/frame)")
    return 0
