"""Procedural interior rooms rendered into every intrinsic channel (our stand-in for the paper's InteriorVideo data).

`generate_scene(seed)` builds a room; `camera_path(scene, T, aspect, seed)` draws the paper's camera path;
`ProceduralRenderer(W, H)` renders all channels per frame; `write_procedural_shot(...)` writes a shot folder.
"""
from x2video.procedural.camera import PathConfig, camera_path
from x2video.procedural.renderer import ProceduralRenderer, RenderConfig
from x2video.procedural.scene import Scene, generate_scene
from x2video.procedural.shotgen import render_frames, write_procedural_shot

__all__ = ["PathConfig", "ProceduralRenderer", "RenderConfig", "Scene", "camera_path", "generate_scene", "render_frames",
           "write_procedural_shot"]
