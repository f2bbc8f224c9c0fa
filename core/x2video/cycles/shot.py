"""Render one procedural room with Cycles into a Blender multi-layer EXR shot (frames + cameras.json + shot.json).

The frames are what a Blender user would hand us (passes + AOVs, `x2video.cycles.passes`), so the
training input goes through the user's input path (`x2video.io.multilayer`). Frames are written
one by one, atomically, and skipped when present: an interrupted shot resumes; shot.json is
written last and marks the shot finished. Needs `bpy` (run in a process of its own).
"""
from __future__ import annotations

import logging
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import bpy
import numpy as np

from x2video.cycles.passes import PASS_FLAGS, compositor_output, configure_view_layer, wire_all_materials
from x2video.cycles.room import build_room, extras_for
from x2video.cycles.variety import GENERATOR_VERSION
from x2video.io.atomic import write_json_atomic
from x2video.io.metadata import FORMAT_NAME, FORMAT_VERSION, cameras_json
from x2video.procedural.camera import PathConfig, camera_path
from x2video.procedural.scene import generate_scene
from x2video.shot import CameraPose

log = logging.getLogger(__name__)

GENERATOR = f"x2video.cycles v{GENERATOR_VERSION}"


@dataclass
class CyclesConfig:
    """How Cycles renders a shot."""

    #: path-tracing samples per pixel of the final frames
    samples: int = 32
    #: OpenImageDenoise on Combined (the target) and, in the compositor, on the light passes (the sampled
    #: diffuse light passes are kept beside them as ``NoisyDiffDir/NoisyDiffInd`` for noise augmentation)
    denoise: bool = True
    #: CPU threads of this Blender process (one process per core is fastest for many small frames)
    threads: int = 1
    #: light bounces in all (diffuse at most 2 of them, glossy 3)
    bounces: int = 4
    #: the exposure aims the 98th percentile of max(R, G, B) of Combined (windows excluded) at this
    target: float = 0.85


def setup_render(width: int, height: int, cfg: CyclesConfig) -> "bpy.types.Scene":
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(cfg.samples)
    scene.cycles.use_adaptive_sampling = True
    scene.cycles.use_denoising = bool(cfg.denoise)
    if cfg.denoise:
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
    scene.cycles.max_bounces = int(cfg.bounces)
    scene.cycles.diffuse_bounces = min(2, int(cfg.bounces))
    scene.cycles.glossy_bounces = min(3, int(cfg.bounces))
    scene.cycles.transmission_bounces = int(cfg.bounces)
    scene.cycles.sample_clamp_indirect = 10.0  # fireflies from small bright paths
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = int(width), int(height), 100
    scene.render.threads_mode, scene.render.threads = "FIXED", max(1, int(cfg.threads))
    scene.render.film_transparent = False
    # the scene stays in memory between a clip's frames (only the camera moves): no re-sync, no BVH rebuild
    # (a 160x112 frame: 2.1 -> 1.75 s at 16 samples on this project's 2-core machine)
    scene.render.use_persistent_data = True
    scene.view_settings.view_transform = "Standard"
    configure_view_layer(scene)
    return scene


def add_camera(poses: list[CameraPose]) -> "bpy.types.Object":
    """A camera keyed on every frame (frame t = pose t), so the Vector pass has motion. Our world is y-up,
    Blender's z-up: cam_to_world is conjugated by the axis change (x, y, z) -> (x, -z, y)."""
    from mathutils import Matrix

    data = bpy.data.cameras.new("camera")
    data.sensor_fit = "VERTICAL"
    data.clip_start, data.clip_end = 0.05, 100.0
    ob = bpy.data.objects.new("camera", data)
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.scene.camera = ob
    axes = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], float)  # ours -> Blender
    for t, p in enumerate(poses):
        ob.matrix_world = Matrix((axes @ np.asarray(p.cam_to_world, float)).tolist())
        ob.keyframe_insert("location", frame=t)
        ob.keyframe_insert("rotation_euler", frame=t)
        if p.fov_y_deg is not None:
            data.angle_y = np.radians(p.fov_y_deg)
    return ob


def blender_poses(poses: list[CameraPose]) -> list[CameraPose]:
    """The poses in Blender's world (z up), as cameras.json beside Blender frames must hold them."""
    axes = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], float)
    return [CameraPose(axes @ np.asarray(p.cam_to_world, float), p.fov_y_deg) for p in poses]


def _render_to(path: Path) -> None:
    bpy.context.scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)


def _read_combined(path: Path) -> np.ndarray:
    """(H, W, 3) linear Combined of a single-layer EXR written by Blender (read back with Blender itself), top row
    first (Blender's pixel buffer starts at the bottom row)."""
    img = bpy.data.images.load(str(path))
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return np.ascontiguousarray(px.reshape(h, w, 4)[::-1, :, :3])


def exposure_gain(scene: "bpy.types.Scene", frames: list[int], target: float) -> float:
    """A gain on every light that puts the 98th percentile of max(R, G, B) of the lit image at `target`:
    a quick low-resolution, low-sample render of a few frames, windows (no geometry behind) excluded."""
    r, c = scene.render, scene.cycles
    keep = (r.resolution_percentage, c.samples, c.use_denoising, r.image_settings.file_format, r.image_settings.color_depth)
    r.resolution_percentage, c.samples, c.use_denoising = 25, 16, False
    r.image_settings.file_format, r.image_settings.color_depth = "OPEN_EXR", "32"
    vals = []
    with tempfile.TemporaryDirectory() as tmp:
        for t in frames:
            scene.frame_set(t)
            f = Path(tmp) / f"probe_{t}.exr"
            _render_to(f)
            vals.append(_read_combined(f).max(-1).ravel())
    r.resolution_percentage, c.samples, c.use_denoising = keep[0], keep[1], keep[2]
    r.image_settings.file_format, r.image_settings.color_depth = keep[3], keep[4]
    v = np.concatenate(vals)
    p98 = float(np.percentile(v[v > 1e-6], 98)) if np.any(v > 1e-6) else 1.0
    return target / max(p98, 1e-6)


def scale_lights(gain: float) -> None:
    """Multiply every light, emitter and the world by `gain` (the exposure lives in the scene, as a user's would)."""
    for light in bpy.data.lights:
        if not light.cycles.is_portal:
            light.energy *= gain
    for mat in bpy.data.materials:
        if mat.use_nodes:
            for n in mat.node_tree.nodes:
                s = n.inputs.get("Emission Strength") if n.bl_idname == "ShaderNodeBsdfPrincipled" else None
                s = n.inputs.get("Strength") if n.bl_idname == "ShaderNodeEmission" else s
                if s is not None:
                    s.default_value *= gain
    world = bpy.context.scene.world
    if world is not None and world.use_nodes:
        for n in world.node_tree.nodes:
            if n.bl_idname == "ShaderNodeBackground":
                n.inputs["Strength"].default_value *= gain


def frame_path(out: Path, t: int) -> Path:
    return out / f"frame_{t:04d}.exr"


def render_frames(scene: "bpy.types.Scene", out: Path, num_frames: int, denoise: bool,
                  progress: Callable[[int, float], None] | None = None, first: int = 0) -> list[float]:
    """Render scene frames first..first+num_frames-1 of `scene` through `compositor_output` into OUT/frame_XXXX.exr
    (numbered from 0), each written atomically and skipped when present (an interrupted shot resumes). Returns the
    seconds of the frames rendered."""
    file_out = compositor_output(scene, denoise_passes=denoise)
    seconds = []
    for t in range(num_frames):
        dst = frame_path(out, t)
        if dst.is_file():
            continue
        t0 = time.perf_counter()
        scene.frame_set(first + t)
        with tempfile.TemporaryDirectory(dir=out, prefix=".tmp_") as tmp:
            file_out.base_path = str(Path(tmp) / "frame_")
            bpy.ops.render.render(write_still=False)
            os.replace(Path(tmp) / f"frame_{first + t:04d}.exr", dst)
        seconds.append(time.perf_counter() - t0)
        if progress is not None:
            progress(t, seconds[-1])
    return seconds


def clip_paths(scene_desc, num_frames: int, clips: int, aspect: float, seed: int, path_cfg: PathConfig | None) -> list[list[CameraPose]]:
    """`clips` camera paths of `num_frames` poses through one room: clip c starts at the room's c-th camera start (corners
    and wall midpoints, in turn) with a random stream of its own, so a room's clips see it from different sides."""
    import dataclasses

    paths = []
    for c in range(clips):
        k = c % max(len(scene_desc.starts), 1)
        view = dataclasses.replace(scene_desc, starts=scene_desc.starts[k:] + scene_desc.starts[:k]) if c else scene_desc
        paths.append(camera_path(view, num_frames, aspect, seed if c == 0 else seed * 7919 + c, path_cfg))
    return paths


def write_room_clips(out_dirs: list[str | Path], seed: int, num_frames: int, width: int, height: int, *, cfg: CyclesConfig | None = None,
                     path_cfg: PathConfig | None = None, fps: float = 10.0, version: int = GENERATOR_VERSION,
                     progress: Callable[[int, float], None] | None = None, light_gain: float | None = None,
                     look: Callable[[dict], dict] | None = None) -> list[Path]:
    """Generate room `seed` (generator `version`), build it in Blender once and render one clip of `num_frames` frames
    along its own camera path into each shot folder of `out_dirs` (resumable per frame; a clip's shot.json is written
    last). Scene set-up (build, shader compile, BVH, exposure probe) is paid once per room, not per clip.

    A variant of a room rendered before (the same room after a look-dev change, `bench.edits_data`): `light_gain`
    is the gain the first render's probe chose (shot.json ``extra.light_gain``; no probe then, so both share the
    exposure), and `look` changes the built scene before the AOVs are wired and the lights scaled (called with
    `build_room`'s result; what it returns is written to shot.json as ``extra.look``)."""
    cfg = cfg or CyclesConfig()
    outs = [Path(d) for d in out_dirs]
    todo = [i for i, o in enumerate(outs) if not (o / "shot.json").is_file()]
    if not todo:
        return outs
    scene_desc = generate_scene(seed)
    paths = clip_paths(scene_desc, num_frames, len(outs), width / height, seed, path_cfg)
    extras = extras_for(scene_desc, seed, version)
    built = build_room(scene_desc, extras)
    looked = look(built) if look is not None else None
    scene = setup_render(width, height, cfg)
    add_camera([p for path in paths for p in path])  # clip c holds scene frames c*T .. c*T + T - 1
    wire_all_materials()
    scene.frame_start, scene.frame_end = 0, len(outs) * num_frames - 1
    probe = sorted({c * num_frames + t for c in todo[:3] for t in (0, num_frames // 2, num_frames - 1)})
    gain = exposure_gain(scene, probe, cfg.target) if light_gain is None else float(light_gain)
    scale_lights(gain)
    light = scene_desc.lighting
    for c in todo:
        out = outs[c]
        out.mkdir(parents=True, exist_ok=True)
        write_json_atomic(out / "cameras.json", cameras_json(blender_poses(paths[c])))
        render_frames(scene, out, num_frames, cfg.denoise, progress, first=c * num_frames)
        write_json_atomic(out / "shot.json", {
            "format": FORMAT_NAME, "version": FORMAT_VERSION, "num_frames": num_frames, "width": width, "height": height, "fps": fps,
            "caption": scene_desc.caption, "objects": {str(k): v for k, v in sorted(built["captions"].items())},
            "irradiance_normalized": False,
            "extra": {"room_seed": int(seed), "clip": c, "clips": len(outs), "light_mood": light.mood, "room_type": scene_desc.room_type,
                      "style": scene_desc.style, "generator": GENERATOR if version >= 3 else "x2video.cycles v2",
                      "renderer": f"Cycles (Blender {bpy.app.version_string})", "samples": cfg.samples,
                      "denoise": cfg.denoise, "light_gain": gain, "path_traced": built["extras"],
                      "material_class": {str(k): v for k, v in built["material_class"].items()},
                      **({"look": looked} if look is not None else {})},
        })
    return outs


def write_room_shot(out_dir: str | Path, seed: int, num_frames: int, width: int, height: int, *, cfg: CyclesConfig | None = None,
                    path_cfg: PathConfig | None = None, fps: float = 10.0, version: int = GENERATOR_VERSION,
                    progress: Callable[[int, float], None] | None = None) -> Path:
    """Generate room `seed`, draw its camera path and render it with Cycles into the shot folder `out_dir` (resumable)."""
    return write_room_clips([out_dir], seed, num_frames, width, height, cfg=cfg, path_cfg=path_cfg, fps=fps, version=version,
                            progress=progress)[0]


def beauty_scene(seed: int, poses: list[CameraPose], width: int, height: int, light_gain: float, threads: int = 1,
                 bounces: int = CyclesConfig.bounces, version: int = GENERATOR_VERSION) -> "bpy.types.Scene":
    """Room `seed` as `write_room_shot` builds it, for rendering the picture alone, as a Blender user would: the
    camera keyed at `poses` (Blender's world, as cameras.json beside the room's frames holds them), every light
    scaled by `light_gain` (the room's shot.json records the gain its exposure probe chose), Combined only (no
    passes, AOVs or compositor), single-layer float EXR. Render frames with `render_beauty`."""
    scene_desc = generate_scene(seed)
    build_room(scene_desc, extras_for(scene_desc, seed, version))
    scene = setup_render(width, height, CyclesConfig(threads=threads, bounces=bounces))
    axes = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], float)  # ours -> Blender (orthogonal)
    add_camera([CameraPose(axes.T @ np.asarray(p.cam_to_world, float), p.fov_y_deg) for p in poses])
    wire_all_materials()  # as the room's build did, so that the scene is the same one
    scale_lights(light_gain)
    return beauty_only(scene)


def beauty_only(scene: "bpy.types.Scene") -> "bpy.types.Scene":
    """`scene` set to render the picture alone, as a Blender user would: Combined only (no passes, AOVs or
    compositor), single-layer float EXR."""
    layer = scene.view_layers[0]
    for flag in PASS_FLAGS:
        setattr(layer, flag, flag == "use_pass_combined")
    while len(layer.aovs):
        layer.aovs.remove(layer.aovs[0])
    scene.use_nodes = False
    s = scene.render.image_settings
    s.file_format, s.color_depth, s.color_mode = "OPEN_EXR", "32", "RGB"
    return scene


def render_beauty(scene: "bpy.types.Scene", t: int, samples: int, *, denoise: bool = True, seed: int = 0) -> tuple[np.ndarray, float]:
    """((H, W, 3) linear Combined of frame `t` at `samples` samples per pixel (adaptive, as the data sets are made),
    OpenImageDenoise'd when `denoise`, noise pattern `seed`; wall seconds of the render and the EXR write)."""
    scene.cycles.samples = int(samples)
    scene.cycles.use_denoising = bool(denoise)
    if denoise:
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
    scene.cycles.seed = int(seed)
    scene.frame_set(t)
    with tempfile.TemporaryDirectory(prefix="x2video_beauty_") as tmp:
        f = Path(tmp) / "beauty.exr"
        t0 = time.perf_counter()
        _render_to(f)
        secs = time.perf_counter() - t0
        return _read_combined(f), secs
