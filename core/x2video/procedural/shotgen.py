"""Render one procedural room along its camera path into all channels plus motion, and write it as a shot folder."""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from x2video.channels import ALL
from x2video.io import ShotWriter
from x2video.procedural.camera import PathConfig, camera_path
from x2video.procedural.motion import motion_field
from x2video.procedural.renderer import ProceduralRenderer, RenderConfig
from x2video.procedural.scene import Scene, generate_scene
from x2video.shot import CameraPose, ShotInfo

#: channels a procedural shot holds (motion besides, on all frames but the last)
SHOT_CHANNELS = ALL
GENERATOR = "x2video.procedural v1"


def shot_info(scene: Scene, poses: list[CameraPose], width: int, height: int, fps: float = 10.0) -> ShotInfo:
    """The ShotInfo (captions, poses, provenance) of a procedural shot."""
    light = scene.lighting
    return ShotInfo(
        num_frames=len(poses), height=height, width=width, channels=SHOT_CHANNELS, fps=fps,
        caption=scene.caption, object_captions=scene.object_captions(), poses=poses, source=f"procedural:{scene.seed}",
        extra={"room_seed": int(scene.seed), "light_mood": light.mood, "room_type": scene.room_type, "style": scene.style,
               "room_size_m": [round(float(v), 3) for v in (scene.width, scene.depth, scene.height)],
               "exposure": float(light.exposure), "generator": GENERATOR,
               "windows": "sky seen through windows: rgb = sky radiance (daylight clips to white), albedo = irradiance = 0, id 0"},
    )


def render_frames(scene: Scene, poses: list[CameraPose], renderer: ProceduralRenderer) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
    """(t, channels) for every frame, with "motion" to frame t+1 on all frames but the last (needs one frame of look-ahead)."""
    if renderer.scene is not scene:
        renderer.set_scene(scene)
    prev = renderer.render(poses[0])
    for t in range(1, len(poses) + 1):
        cur = renderer.render(poses[t]) if t < len(poses) else None
        if cur is not None:
            prev["motion"] = motion_field(prev["depth"], poses[t - 1], cur["depth"], poses[t])
        yield t - 1, prev
        prev = cur


def write_procedural_shot(out_dir: str | Path, seed: int, num_frames: int, width: int, height: int, *,
                          renderer: ProceduralRenderer | None = None, path_cfg: PathConfig | None = None,
                          fps: float = 10.0, overwrite: bool = True, progress: Callable[[int], None] | None = None) -> Path:
    """Generate room `seed`, draw its camera path, render `num_frames` frames and write the shot folder `out_dir`.

    shot.json is written last, so its presence marks a finished shot."""
    if num_frames < 1:
        raise ValueError(f"num_frames must be at least 1, got {num_frames}")
    own = renderer is None
    renderer = renderer or ProceduralRenderer(width, height, RenderConfig())
    if (renderer.width, renderer.height) != (width, height):
        raise ValueError(f"renderer is {renderer.width}x{renderer.height}, shot asks for {width}x{height}")
    try:
        scene = generate_scene(seed)
        poses = camera_path(scene, num_frames, width / height, seed, path_cfg)
        renderer.set_scene(scene, exposure_poses=poses)  # sets the exposure recorded in shot.json
        info = shot_info(scene, poses, width, height, fps)
        with ShotWriter(out_dir, info, irradiance_normalized=True, overwrite=overwrite) as w:
            for t, ch in render_frames(scene, poses, renderer):
                w.write_frame(t, ch)
                if progress is not None:
                    progress(t)
    finally:
        if own:
            renderer.release()
    return Path(out_dir)
