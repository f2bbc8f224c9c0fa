"""`x2video dataset truth`: render a truth apart from the passes for finished Cycles shots (``SHOT/truth/``, issue 49).

A Cycles shot's Combined and its irradiance pass come out of one render, so a tier that passes irradiance
through copies the truth's noise. For each finished shot of a split this renders the same scene, camera and
lights again (a procedural room from its seed and generator version, `x2video.cycles.shot.beauty_scene`; an
outside scene from its module, `x2video.cycles.outside.render.build_scene`), with the exposure gain the shot
recorded, Combined only, at more samples than the passes and another noise seed, OpenImageDenoise'd as the
Combined is. Frames go to ``SHOT/truth/000000.exr ...`` (float R, G, B; written atomically, skipped when
there: resumable per frame); ``SHOT/truth/truth.json`` records the samples, the seed and each frame's wall
and CPU seconds, and says ``complete`` once every frame is there. One Blender process per shot, in turn
(this module imports bpy only inside that process). The reader is `x2video.io.truth`.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import resource
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from x2video.io.truth import FORMAT, RECORD, TRUTH_DIR, missing_frames, truth_frame_path

#: Cycles' noise seed of the passes (`x2video.cycles.shot.setup_render` leaves Blender's default)
PASSES_SEED = 0
#: the fewest samples the default picks (2x the passes' otherwise)
MIN_SAMPLES = 32


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)  # Cycles' render threads are this process's
    return r.ru_utime + r.ru_stime


def scene_of(shot_dir: Path, meta: dict) -> dict:
    """How to build a shot's scene again, from its shot.json: {"kind": "room", "seed", "version"} or {"kind":
    "outside", "scene"}; ValueError naming the shot and the field when it cannot be rebuilt."""
    from x2video.cycles.outside import GENERATOR as OUTSIDE
    from x2video.cycles.outside import SCENES

    extra = meta.get("extra") or {}
    gen = str(extra.get("generator", ""))
    where = f"{shot_dir / 'shot.json'}"
    if "light_gain" not in extra:
        raise ValueError(f"{where}: no extra.light_gain (not a Cycles shot of `x2video dataset make --renderer cycles` or"
                         " `x2video dataset outside`), so its exposure cannot be matched")
    if "look" in extra:
        raise ValueError(f"{where}: a look variant (extra.look): its changes to the scene are not recorded, so the scene"
                         " cannot be built again")
    if gen == OUTSIDE:
        if extra.get("scene") not in SCENES:
            raise ValueError(f"{where}: extra.scene is {extra.get('scene')!r}, not one of the outside scenes {', '.join(SCENES)}")
        return {"kind": "outside", "scene": extra["scene"]}
    if gen.startswith("x2video.cycles v") and gen[len("x2video.cycles v"):].isdigit():
        if "room_seed" not in extra:
            raise ValueError(f"{where}: no extra.room_seed")
        return {"kind": "room", "seed": int(extra["room_seed"]), "version": int(gen[len("x2video.cycles v"):])}
    raise ValueError(f"{where}: extra.generator is {gen!r}; a truth apart is rendered for procedural Cycles rooms"
                     f" ('x2video.cycles vN') and the outside scenes ({OUTSIDE!r})")


def default_samples(meta: dict) -> int:
    """2x the passes' samples, at least `MIN_SAMPLES`."""
    return max(2 * int((meta.get("extra") or {}).get("samples") or 0), MIN_SAMPLES)


def open_scene(shot_dir: Path, meta: dict, threads: int):
    """The shot's scene built again in this (Blender) process, set to render Combined alone."""
    import numpy as np

    from x2video.cycles.shot import CyclesConfig, beauty_only, beauty_scene, scale_lights, setup_render
    from x2video.io.metadata import parse_cameras_json

    how = scene_of(shot_dir, meta)
    n, w, h = int(meta["num_frames"]), int(meta["width"]), int(meta["height"])
    poses = parse_cameras_json(shot_dir / "cameras.json", n)  # Blender's world, as both builders wrote them
    gain = float(meta["extra"]["light_gain"])
    if how["kind"] == "room":
        return beauty_scene(how["seed"], poses, w, h, gain, threads=threads, version=how["version"])
    from x2video.cycles.outside.build import add_camera
    from x2video.cycles.outside.render import build_scene
    from x2video.cycles.passes import wire_all_materials

    _, spec = build_scene(how["scene"])
    scene = setup_render(w, h, CyclesConfig(threads=threads))
    add_camera([np.asarray(p.cam_to_world, float) for p in poses], spec.fov_y_deg)
    wire_all_materials()  # as the shot's build did, so that the scene is the same one
    scale_lights(gain)
    return beauty_only(scene)


def begin_record(shot_dir: Path, meta: dict, samples: int, seed: int) -> dict:
    """SHOT/truth/truth.json as a run starts: the one there when it asked for the same samples and seed (a resumed
    truth), a new one when there is none; ValueError when the truth there was rendered otherwise."""
    f = shot_dir / TRUTH_DIR / RECORD
    if f.is_file():
        rec = json.loads(f.read_text())
        if (rec.get("samples"), rec.get("seed")) != (samples, seed):
            raise ValueError(f"{f}: this truth was rendered at {rec.get('samples')} spp seed {rec.get('seed')}, asked for {samples} spp"
                             f" seed {seed}; ask for the same, or remove {f.parent} to render it again")
        return rec
    extra = meta.get("extra") or {}
    return {"format": FORMAT, "samples": samples, "seed": seed, "denoise": "OpenImageDenoise", "frames": int(meta["num_frames"]),
            "width": int(meta["width"]), "height": int(meta["height"]), "light_gain": float(extra["light_gain"]),
            "passes": {"samples": extra.get("samples"), "seed": PASSES_SEED, "denoise": extra.get("denoise")},
            "scene": scene_of(shot_dir, meta), "complete": False, "seconds": {}, "cpu_seconds": {}}


def render_truth(shot_dir: str | Path, samples: int | None = None, seed: int = 1, threads: int = 1,
                 progress: Callable[[int, float], None] | None = None) -> dict:
    """Render the missing frames of SHOT/truth/ in this process (imports bpy); returns the record written."""
    import bpy
    import numpy as np

    from x2video.cycles.shot import render_beauty
    from x2video.io.atomic import write_json_atomic
    from x2video.io.image import write_exr

    d = Path(shot_dir)
    meta = json.loads((d / "shot.json").read_text())
    samples = int(samples or default_samples(meta))
    check_settings(samples, seed)
    rec = begin_record(d, meta, samples, seed)
    n = int(meta["num_frames"])
    todo = missing_frames(d, n)
    (d / TRUTH_DIR).mkdir(exist_ok=True)
    write_json_atomic(d / TRUTH_DIR / RECORD, rec)
    if todo:
        t0 = time.perf_counter()
        scene = open_scene(d, meta, threads)
        rec["renderer"] = f"Cycles (Blender {bpy.app.version_string})"
        rec.setdefault("setup_seconds", []).append(round(time.perf_counter() - t0, 3))  # one per run: the scene's build
        for t in todo:
            w0, c0 = time.perf_counter(), _cpu()
            img, _ = render_beauty(scene, t, samples, denoise=True, seed=seed)
            if img.shape[:2] != (rec["height"], rec["width"]):
                raise ValueError(f"{d}: frame {t} rendered {img.shape[1]}x{img.shape[0]}, the shot is {rec['width']}x{rec['height']}")
            write_exr(truth_frame_path(d, t), {c: img[..., i].astype(np.float32) for i, c in enumerate("RGB")}, "float")
            rec["seconds"][str(t)] = round(time.perf_counter() - w0, 3)
            rec["cpu_seconds"][str(t)] = round(_cpu() - c0, 3)
            write_json_atomic(d / TRUTH_DIR / RECORD, rec)
            if progress is not None:
                progress(t, rec["seconds"][str(t)])
    rec["complete"] = not missing_frames(d, n)
    write_json_atomic(d / TRUTH_DIR / RECORD, rec)
    return rec


def check_settings(samples: int, seed: int) -> None:
    if samples < 1:
        raise ValueError(f"--samples must be at least 1 (got {samples})")
    if seed == PASSES_SEED:
        raise ValueError(f"--seed {seed} is the passes' own noise seed; a truth apart needs another")


@dataclass
class TruthJob:
    shot: str
    samples: int
    seed: int
    threads: int


def _work(job: TruthJob) -> None:
    """Worker process: one shot's truth (imports bpy here; Blender's progress lines go to /dev/null)."""
    from x2video.cycles.dataset import _quiet

    _quiet()
    render_truth(job.shot, job.samples, job.seed, job.threads)


def make_truth(args: argparse.Namespace) -> int:
    """The command: every finished shot of `--split` gets a complete truth apart (one Blender process per shot)."""
    from x2video.cycles.dataset import require_bpy
    from x2video.io.dataset import shot_dirs

    seed, asked = int(args.seed), int(args.samples or 0)
    check_settings(asked or MIN_SAMPLES, seed)
    threads = int(args.threads or 0) or (os.cpu_count() or 1)
    dirs = [d for s in args.split.split(",") if s for d in shot_dirs(args.data, s)]
    if not dirs:
        raise SystemExit(f"{args.data}: no finished shots in split(s) {args.split!r} (expected DATA/<split>/<shot>/shot.json)")
    metas = {d: json.loads((d / "shot.json").read_text()) for d in dirs}
    bad = []
    for d, m in metas.items():
        try:
            scene_of(d, m)
        except ValueError as exc:
            bad.append(str(exc))
    if bad:  # before any render: a set the command cannot finish is said at once
        raise SystemExit(f"{len(bad)} of {len(dirs)} shot(s) cannot get a truth apart:\n  " + "\n  ".join(bad[:10]))
    require_bpy()
    done = 0
    for d in dirs:
        meta = metas[d]
        samples = asked or default_samples(meta)
        rec_file = d / TRUTH_DIR / RECORD
        if rec_file.is_file():
            old = json.loads(rec_file.read_text())
            if old.get("complete") and (old.get("samples"), old.get("seed")) == (samples, seed) and not missing_frames(d, int(meta["num_frames"])):
                done += 1
                continue
        before = len(missing_frames(d, int(meta["num_frames"])))
        t0 = time.perf_counter()
        proc = mp.get_context("spawn").Process(target=_work, args=(TruthJob(str(d), samples, seed, threads),), name=f"truth-{d.name}")
        proc.start()
        proc.join()
        left = len(missing_frames(d, int(meta["num_frames"])))
        if proc.exitcode != 0:
            raise RuntimeError(f"{d}: the Blender process exited with {proc.exitcode} after {before - left} new truth frame(s)"
                               " (its error is above); run the same command again to resume")
        rec = json.loads(rec_file.read_text())
        cpu = sum(rec["cpu_seconds"].values()) / max(len(rec["cpu_seconds"]), 1)
        print(f"{d.name}: {before - left} truth frame(s) at {samples} spp seed {seed} in {time.perf_counter() - t0:.0f} s"
              f" ({cpu:.1f} CPU s a frame)", flush=True)
    print(f"{len(dirs)} shot(s) in {args.data} split {args.split}: {done} had their truth apart, {len(dirs) - done} rendered now")
    return 0
