"""Outside test scenes: hand-written Blender scenes in a style of their own, never trained on (issue 28 item 2).

Where the procedural rooms (`x2video.cycles.room`) are axis-aligned boxes from one generator, these
are written by hand, one module per scene, straight in bpy: bevelled cabinets, cylinders, tapered
hoods, rotated furniture, coloured lights, a mirror and a night window. Each scene has a smooth
camera move and is rendered into the same Blender multi-layer EXR shot as the procedural rooms
(`x2video.cycles.outside.render.write_outside_shot`), with an object id per object and its
material class in shot.json (``extra.material_class``, see `x2video.cycles.classes`).

This package's ``__init__`` does not import bpy; the scene modules do.
"""
from __future__ import annotations

#: the scenes, in rendering order (module names under this package)
SCENES = ("kitchen", "corridor", "night_mirror")
GENERATOR = "x2video.cycles.outside v1"
