"""The README's picture: one frame of an outside scene as the formula, tier 1, the diffusion tier and Cycles at 4 samples
make it, beside the ground truth, each labelled with its PSNR against the ground truth and its seconds per frame.

    python -m bench.side_by_side --shot DATA/outside-320x224-16spp/test/kitchen --frame 6 [--cycles-samples 4] [--threads 2] [--weights DIR]
        [--png docs/side_by_side.png] [--out bench/results/side_by_side/side_by_side.json]

`--shot` is a scene folder from `x2video dataset outside` (the hand-written Cycles scenes: shot.json names the scene,
its light gain and the samples it was rendered at). Panels, left to right:

    formula (albedo × irradiance)   tier 0, `RenderSettings(quality="formula")`
    tier 1                          the shipped tier-1 net, `quality="residual"`
    diffusion (fast preset)         the diffusion tier, `quality="diffusion", preset="fast"` (LCM-2, or DDIM-4 without LCM weights)
    Cycles 4 spp + OIDN             the same scene rebuilt from its module (`x2video.cycles.outside`), camera and light gain
                                    as the data set's, only the picture rendered (no passes or compositor), OpenImageDenoise'd,
                                    noise seed 1 (the passes' is 0), in a Blender process of its own (bpy stays out of
                                    the torch process)
    ground truth                    the shot's truth apart (SHOT/truth/, `x2video dataset truth`: more samples, another
                                    seed) when it has one, else its rgb: Cycles at the data set's samples, OpenImageDenoise'd

Every tier renders the whole shot through `x2video.Renderer` (the library's one public API) and the picture shows frame
`--frame`; seconds per frame are wall seconds of the render over the shot's frame count, after one untimed warm-up
render of the same tier (first-call costs: the diffusion engine's graphs), with a fresh Renderer (it pays its own
conditioning). Cycles renders every frame of the shot too; its seconds per frame are the render call per frame (scene
sync after the first frame, path tracing, denoising, writing the EXR), the scene built and one 1-sample render made
beforehand (Blender's start-up, the scene build, kernel and OIDN loading and the first scene sync are recorded
apart). CPU seconds per frame (all threads of the rendering process) are in the JSON beside the wall seconds. PSNR and
SSIM are on display images in the shot's units (`bench.ptscore`: the tiers' frames divided by the shot's
irradiance_scale, `x2video.channels.tonemap`), for the picture's frame and as means over the shot.

Writes the PNG (`--png`, default docs/side_by_side.png; matplotlib: pip install 'x2video-studio[bench]') and the
figures as JSON (`--out`, default bench/results/side_by_side/side_by_side.json), paths in them machine-independent.
"""
from __future__ import annotations

import argparse
import io
import json
import multiprocessing as mp
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from bench.common import clean_json, command, results_path
from bench.ptscore import display, render_timed, truth
from x2video.io.truth import ground_truth

DOCS = Path(__file__).resolve().parents[1] / "docs"
#: the README shows the picture about 900 px wide: keep the file small
PNG_BUDGET_BYTES = 400_000
#: (key, label, RenderSettings quality, preset) of the tiers' panels, left to right
TIER_PANELS = (("formula", "formula (albedo × irradiance)", "formula", None),
               ("residual", "tier 1", "residual", None),
               ("diffusion", "diffusion (fast preset)", "diffusion", "fast"))
GROUND_TRUTH = "ground truth"


@dataclass
class Panel:
    key: str
    label: str
    image: np.ndarray  # display image (H, W, 3) in [0, 1]
    seconds_per_frame: float | None = None  # wall
    cpu_seconds_per_frame: float | None = None
    psnr: float | None = None  # of the picture's frame against the ground truth
    ssim: float | None = None
    psnr_shot: float | None = None  # means over the shot's frames
    ssim_shot: float | None = None
    caption: str = ""  # the second line under the label when there is no PSNR (the ground truth)
    extra: dict[str, Any] = field(default_factory=dict)


def scored(panel: Panel, gt: np.ndarray, shot_pairs: Sequence[tuple[np.ndarray, np.ndarray]] | None = None) -> Panel:
    """`panel` with PSNR and SSIM of its image against `gt` (display images), and their means over `shot_pairs`."""
    from x2video.metrics.image import psnr, ssim

    panel.psnr, panel.ssim = float(psnr(panel.image, gt)), float(ssim(panel.image, gt))
    if shot_pairs:
        panel.psnr_shot = float(np.mean([psnr(p, g) for p, g in shot_pairs]))
        panel.ssim_shot = float(np.mean([ssim(p, g) for p, g in shot_pairs]))
    return panel


# --------------------------------------------------------------------------------------------- Cycles (own process)
def _quiet() -> None:
    """Blender prints a line per tile and pass to the C stdout: send it to /dev/null in the worker."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)


def _cycles_worker(job: dict) -> dict:
    """In a Blender process: outside scene `job["scene"]` built as `write_outside_shot` builds it (same module, camera
    move and light gain), only Combined rendered (as `x2video.cycles.shot.beauty_scene` strips a room), every frame at
    `job["samples"]` samples, OpenImageDenoise'd, noise seed `job["seed"]`."""
    t_start = time.perf_counter()
    import bpy  # first: bmesh and mathutils, which the scene modules import, come with it

    from x2video.cycles.outside.build import add_camera, camera_poses
    from x2video.cycles.outside.render import build_scene
    from x2video.cycles.passes import wire_all_materials
    from x2video.cycles.shot import CyclesConfig, beauty_only, render_beauty, scale_lights, setup_render

    t0 = t_build = time.perf_counter()
    _, spec = build_scene(job["scene"])
    n = int(job["num_frames"])
    scene = setup_render(job["width"], job["height"], CyclesConfig(samples=job["samples"], threads=job["threads"]))
    add_camera(camera_poses(spec, n), spec.fov_y_deg)
    wire_all_materials()  # as the data set's build did, so that the scene is the same one
    scene.frame_start, scene.frame_end = 0, n - 1
    scale_lights(job["gain"])
    beauty_only(scene)
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    render_beauty(scene, job["frame"], 1, seed=job["seed"])  # kernels, OIDN and the first scene sync: untimed
    first = time.perf_counter() - t0
    image, secs, cpu = None, [], []
    for t in range(n):
        c0 = time.process_time()
        img, sec = render_beauty(scene, t, job["samples"], seed=job["seed"])
        cpu.append(time.process_time() - c0)
        secs.append(sec)
        if t == job["frame"]:
            image = img
    return {"image": image, "seconds": secs, "cpu_seconds": cpu, "build_seconds": build, "first_render_seconds": first,
            "import_seconds": t_build - t_start, "blender": bpy.app.version_string}


def render_cycles(job: dict) -> dict:
    """`_cycles_worker` in a spawned process (bpy wants a process of its own); adds the process's start-up seconds."""
    t0 = time.perf_counter()
    with mp.get_context("spawn").Pool(1, initializer=_quiet) as pool:
        res = pool.apply(_cycles_worker, (job,))
    res["process_seconds"] = time.perf_counter() - t0
    return res


def cycles_job(shot_dir: Path, info: dict, frame: int, samples: int, threads: int, seed: int) -> dict:
    """What the Cycles process needs to rebuild the outside scene of `shot_dir` (SystemExit when it is not one)."""
    extra = info.get("extra", {})
    from x2video.cycles.outside import GENERATOR, SCENES

    if extra.get("generator") != GENERATOR or extra.get("scene") not in SCENES or "light_gain" not in extra:
        raise SystemExit(f"--shot {shot_dir}: not a scene of `x2video dataset outside` ({GENERATOR}: {', '.join(SCENES)}); "
                         "shot.json must name the scene and its light gain (or pass --no-cycles)")
    return {"scene": extra["scene"], "num_frames": int(info["num_frames"]), "width": int(info["width"]), "height": int(info["height"]),
            "gain": float(extra["light_gain"]), "frame": frame, "samples": samples, "threads": threads, "seed": seed}


# --------------------------------------------------------------------------------------------- the tiers
def render_tiers(model: Any, shot: Any, frame: int, gts: list[np.ndarray]) -> list[Panel]:
    """The tiers' panels: each tier renders the whole shot twice through `x2video.Renderer` (a warm-up, then the timed
    render with a fresh Renderer), scored against the ground truth's display images `gts`."""
    import x2video
    from x2video.render.settings import select_steps

    scale = float(shot.info.irradiance_scale)
    panels = []
    for key, label, quality, preset in TIER_PANELS:
        settings = x2video.RenderSettings(quality=quality, preset=preset, base="off")
        render_timed(x2video.Renderer(model), shot, settings)  # untimed warm-up
        c0 = time.process_time()
        frames, secs = render_timed(x2video.Renderer(model), shot, settings)
        cpu = time.process_time() - c0
        disp = display(frames, scale)
        n = len(frames)
        extra: dict[str, Any] = {"quality": quality}
        if preset:
            s = select_steps(settings, model)
            extra.update(preset=preset, sampler=s.sampler, steps=s.steps)
        p = Panel(key, label, disp[frame], secs / n, cpu / n, extra=extra)
        panels.append(scored(p, gts[frame], list(zip(disp, gts))))
        print(f"{label}: PSNR {p.psnr:.2f} dB (shot {p.psnr_shot:.2f}), {p.seconds_per_frame:.3f} s/frame", flush=True)
    return panels


def cycles_panel(res: dict, samples: int, gts: list[np.ndarray], frame: int) -> Panel:
    from x2video.channels import tonemap

    p = Panel("cycles", f"Cycles {samples} spp + OIDN", tonemap(np.asarray(res["image"], np.float32)),
              float(np.mean(res["seconds"])), float(np.mean(res["cpu_seconds"])),
              extra={"samples": samples, "frames_timed": len(res["seconds"]), "build_seconds": round(res["build_seconds"], 3),
                     "first_render_seconds": round(res["first_render_seconds"], 3),
                     "import_seconds": round(res["import_seconds"], 3), "process_seconds": round(res["process_seconds"], 3),
                     "blender": res["blender"]})
    return scored(p, gts[frame])


def ground_truth_panel(info: dict, gt: np.ndarray, record: dict | None = None) -> Panel:
    """The ground truth: the shot's truth apart when it has one (`record`, SHOT/truth/truth.json: its samples, seed and
    seconds), else the shot's rgb (its seconds per frame as the data set's build recorded them: all passes, its own threads)."""
    if record is not None:
        secs = record.get("seconds") or {}
        mean = round(sum(secs.values()) / len(secs), 3) if secs else None
        label = f"{GROUND_TRUTH}: Cycles {record['samples']} spp + OIDN"  # the title's width: its seed goes below
        apart = f"seed {record['seed']}, apart from the passes"
        caption = f"{mean:g} s/frame · {apart}" if mean is not None else apart
        return Panel("ground_truth", label, gt, mean, caption=caption,
                     extra={"samples": record["samples"], "denoise": record.get("denoise"), "seed": record["seed"],
                            "apart": True, "seconds_note": "recorded by `x2video dataset truth`: the beauty render alone, wall"})
    extra = info.get("extra", {})
    samples, secs, threads = extra.get("samples"), extra.get("seconds_per_frame"), extra.get("threads")
    label = f"{GROUND_TRUTH}: Cycles {samples} spp + OIDN" if samples else GROUND_TRUTH
    caption = (f"{secs:g} s/frame at build ({threads} thread{'s' if threads != 1 else ''})" if secs is not None
               else "the shot's rgb")
    return Panel("ground_truth", label, gt, float(secs) if secs is not None else None, caption=caption,
                 extra={"samples": samples, "denoise": extra.get("denoise"), "seed": 0, "threads": threads, "apart": False,
                        "seconds_note": "recorded by the data set's build: the render of every pass and the compositor, wall"})


# --------------------------------------------------------------------------------------------- the picture
def panel_caption(p: Panel) -> str:
    if p.psnr is None:
        return p.caption
    secs = "—" if p.seconds_per_frame is None else f"{p.seconds_per_frame:.2f}" if p.seconds_per_frame >= 0.1 else f"{p.seconds_per_frame:.3f}"
    return f"PSNR {p.psnr:.2f} dB · {secs} s/frame"


def compose(panels: list[Panel], path: Path, footer: str = "") -> dict:
    """One row of panels at their own pixel size, each titled with its label and `panel_caption`, `footer` below; written
    to `path` as PNG (palette PNG when the RGB one would be over PNG_BUDGET_BYTES). Returns {'bytes', 'palette', 'size'}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    from x2video.io.atomic import atomic_path

    h, w = panels[0].image.shape[:2]
    dpi, gap, top, bottom = 100, 8, 62, 32 if footer else 6  # pixels
    fs = max(11.0, w / 22)  # label font in pixels: readable when the row is shown about 900 px wide
    W, H = len(panels) * w + (len(panels) + 1) * gap, top + h + bottom
    fig = plt.figure(figsize=(W / dpi, H / dpi), dpi=dpi)
    fig.patch.set_facecolor("white")
    pt = 72 / dpi  # points per pixel
    for i, p in enumerate(panels):
        x = gap + i * (w + gap)
        ax = fig.add_axes((x / W, bottom / H, w / W, h / H))
        ax.imshow(np.clip(p.image, 0, 1), interpolation="nearest")
        ax.set_axis_off()
        cx = (x + w / 2) / W
        fig.text(cx, (bottom + h + 34) / H, p.label, ha="center", va="bottom", fontsize=fs * pt, fontweight="bold")
        fig.text(cx, (bottom + h + 6) / H, panel_caption(p), ha="center", va="bottom", fontsize=0.9 * fs * pt, color="#333333")
    if footer:
        fig.text(gap / W, 8 / H, footer, ha="left", va="bottom", fontsize=0.75 * fs * pt, color="#555555")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, facecolor="white")
    plt.close(fig)
    img = Image.open(io.BytesIO(buf.getvalue())).convert("RGB")
    out = io.BytesIO()
    img.save(out, format="PNG", optimize=True)
    palette = out.tell() > PNG_BUDGET_BYTES
    if palette:
        out = io.BytesIO()
        img.quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.FLOYDSTEINBERG).save(out, format="PNG", optimize=True)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(out.getvalue())
    return {"bytes": len(out.getvalue()), "palette": palette, "size": list(img.size)}


def panel_rows(panels: list[Panel]) -> list[dict]:
    return [{"key": p.key, "label": p.label, "psnr": p.psnr, "ssim": p.ssim, "psnr_shot": p.psnr_shot, "ssim_shot": p.ssim_shot,
             "seconds_per_frame": p.seconds_per_frame, "cpu_seconds_per_frame": p.cpu_seconds_per_frame, "caption": panel_caption(p), **p.extra}
            for p in panels]


def write_outputs(panels: list[Panel], png: Path, out: Path, header: dict, footer: str = "") -> dict:
    """Draw the PNG and write the JSON (header + panels + the PNG's path and size); returns the JSON's content."""
    from x2video.io.atomic import write_json_atomic
    from x2video.io.paths import portable_path

    drawn = compose(panels, png, footer)
    result = clean_json({**header, "png": {"path": portable_path(png), **drawn}, "panels": panel_rows(panels)})
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out, result)
    return result


# --------------------------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shot", type=Path, required=True, help="a scene folder of `x2video dataset outside` (DATA/test/kitchen)")
    ap.add_argument("--frame", type=int, default=6, help="the frame shown (default 6)")
    ap.add_argument("--cycles-samples", type=int, default=4, help="samples per pixel of the Cycles panel (default 4)")
    ap.add_argument("--cycles-seed", type=int, default=1, help="its noise seed (default 1: the data set renders with 0)")
    ap.add_argument("--no-cycles", action="store_true", help="leave the Cycles panel out (no bpy needed)")
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads and Cycles threads (default 2)")
    ap.add_argument("--weights", default=None, help="model folder (default: the shipped weights)")
    ap.add_argument("--png", type=Path, default=DOCS / "side_by_side.png", help="the picture (default docs/side_by_side.png)")
    ap.add_argument("--out", type=Path, default=None, help="the figures' JSON (default bench/results/side_by_side/side_by_side.json)")
    args = ap.parse_args(argv)
    out = args.out or results_path("side_by_side")

    import torch

    import x2video
    from x2video.eval.machine import machine_info, machine_label
    from x2video.io.paths import portable_path

    torch.set_num_threads(args.threads)
    t_all = time.perf_counter()
    info_file = args.shot / "shot.json"
    if not info_file.is_file():
        raise SystemExit(f"--shot {args.shot}: no shot.json (a finished shot folder of `x2video dataset outside`)")
    info = json.loads(info_file.read_text())
    shot = x2video.load_shot(args.shot)
    if not 0 <= args.frame < shot.num_frames:
        raise SystemExit(f"--frame {args.frame}: the shot has frames 0..{shot.num_frames - 1}")
    if not shot.has("rgb"):
        raise SystemExit(f"--shot {args.shot}: no rgb ground truth")
    gt_apart = ground_truth(shot, args.shot)
    if gt_apart.record is not None and not args.no_cycles and int(gt_apart.record["seed"]) == args.cycles_seed:
        raise SystemExit(f"--cycles-seed {args.cycles_seed} is the seed of the shot's truth apart ({gt_apart.label}): the Cycles panel"
                         " would share its noise with what it is scored against; pick another")
    job = None if args.no_cycles else cycles_job(args.shot, info, args.frame, args.cycles_samples, args.threads, args.cycles_seed)
    load0 = os.getloadavg()
    gts = truth(shot)
    from x2video.weights import load_model, shipped_weights

    model = load_model(args.weights)
    panels = render_tiers(model, shot, args.frame, gts)
    cycles = None
    if job is not None:
        cycles = render_cycles(job)
        panels.append(cycles_panel(cycles, args.cycles_samples, gts, args.frame))
        p = panels[-1]
        print(f"{p.label}: PSNR {p.psnr:.2f} dB, {p.seconds_per_frame:.3f} s/frame (scene build {cycles['build_seconds']:.1f} s, "
              f"first render {cycles['first_render_seconds']:.1f} s, process {cycles['process_seconds']:.1f} s)", flush=True)
    panels.append(ground_truth_panel(info, gts[args.frame], gt_apart.record))

    from bench.pareto.measure import weights_digest

    machine = machine_info(model.device)
    scene = info.get("extra", {}).get("scene") or args.shot.name
    h, w = shot.size
    footer = (f"{scene}, frame {args.frame} of {shot.num_frames}, {w}×{h} · PSNR on display images against the ground truth · "
              f"wall seconds per frame over the shot's {shot.num_frames} frames, {args.threads} threads, {machine_label(machine)}")
    header = {
        "format": "x2video-side-by-side",
        "command": command("side_by_side", argv),
        "machine": machine,
        "threads": args.threads,
        "load_average_start": [round(v, 2) for v in load0],
        "load_average_end": [round(v, 2) for v in os.getloadavg()],
        "weights": portable_path(args.weights) if args.weights else "shipped",
        "weights_sha256": weights_digest(Path(args.weights) if args.weights else shipped_weights()),
        "shot": portable_path(args.shot), "truth": gt_apart.label, "scene": scene, "frame": args.frame, "frames": shot.num_frames, "size": [w, h],
        "cycles": None if cycles is None else {"samples": args.cycles_samples, "seed": args.cycles_seed, "threads": args.threads,
                                               "seconds_per_frame": [round(s, 3) for s in cycles["seconds"]]},
        "note": "PSNR/SSIM on display images (tonemap: clip, sRGB) in the shot's units against the ground truth ('truth'), for the picture's "
                "frame (psnr, ssim) and as means over the shot (psnr_shot, ssim_shot); seconds_per_frame: wall seconds of the whole "
                "shot's render over its frames after an untimed warm-up (Cycles: the render call per frame, the scene built and one "
                "1-sample render made beforehand); cpu_seconds_per_frame: CPU seconds of the rendering process, all threads",
        "wall_seconds": round(time.perf_counter() - t_all, 2),
    }
    result = write_outputs(panels, args.png, out, header, footer)
    print(f"wrote {args.png} ({result['png']['bytes'] / 1000:.0f} kB) and {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
