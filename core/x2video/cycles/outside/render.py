"""Render one outside scene with Cycles into a Blender multi-layer EXR shot (frames + cameras.json + shot.json).

The same shot as a procedural room's (`x2video.cycles.shot`): the project's passes, AOVs, compositor,
exposure and camera-pose helpers; frames written atomically and skipped when present (resumable);
shot.json last. Needs `bpy` (run in a process of its own).
"""
from __future__ import annotations

import importlib
import json
import shutil
from pathlib import Path
from typing import Callable

import bpy

from x2video.cycles.outside import GENERATOR, SCENES
from x2video.cycles.outside.build import Builder, add_camera, camera_poses
from x2video.cycles.passes import wire_all_materials
from x2video.cycles.shot import CyclesConfig, exposure_gain, render_frames, scale_lights, setup_render
from x2video.io.atomic import write_json_atomic
from x2video.io.metadata import FORMAT_NAME, FORMAT_VERSION, cameras_json
from x2video.shot import CameraPose


def build_scene(name: str) -> tuple[Builder, object]:
    """Clear the Blender file and build scene `name`; returns its Builder and SceneSpec."""
    if name not in SCENES:
        raise ValueError(f"unknown outside scene {name!r}; choose from {', '.join(SCENES)}")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    b = Builder()
    spec = importlib.import_module(f"x2video.cycles.outside.{name}").build(b)
    return b, spec


def write_outside_shot(name: str, out_dir: str | Path, num_frames: int, width: int, height: int, *, cfg: CyclesConfig | None = None,
                       fps: float = 10.0, progress: Callable[[int, float], None] | None = None) -> Path:
    """Build outside scene `name` and render its camera move into the shot folder `out_dir` (resumable)."""
    cfg = cfg or CyclesConfig()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.glob(".tmp_*"):  # a frame a killed run was writing (one process per scene folder)
        shutil.rmtree(stale, ignore_errors=True)
    b, spec = build_scene(name)
    scene = setup_render(width, height, cfg)
    mats = camera_poses(spec, num_frames)
    add_camera(mats, spec.fov_y_deg)
    wire_all_materials()
    scene.frame_start, scene.frame_end = 0, num_frames - 1
    # the exposure is measured once and kept, so that a resumed shot's frames match the first run's
    gain_file = out / ".light_gain.json"
    if gain_file.is_file():
        gain = float(json.loads(gain_file.read_text())["gain"])
    else:
        gain = exposure_gain(scene, sorted({0, num_frames // 2, num_frames - 1}), cfg.target)
        write_json_atomic(gain_file, {"gain": gain})
    scale_lights(gain)
    write_json_atomic(out / "cameras.json", cameras_json([CameraPose(m, spec.fov_y_deg) for m in mats]))
    seconds = render_frames(scene, out, num_frames, cfg.denoise, progress)
    write_json_atomic(out / "shot.json", {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "num_frames": num_frames, "width": width, "height": height, "fps": fps,
        "caption": spec.caption, "objects": {str(k): v for k, v in sorted(b.captions.items())}, "irradiance_normalized": False,
        "extra": {"generator": GENERATOR, "scene": name, "materials": b.materials,
                  "material_class": {str(k): v for k, v in sorted(b.classes.items())},
                  "renderer": f"Cycles (Blender {bpy.app.version_string})", "samples": cfg.samples, "denoise": cfg.denoise,
                  "light_gain": gain, "threads": cfg.threads,
                  "seconds_per_frame": round(sum(seconds) / len(seconds), 2) if seconds else None},
    })
    return out
