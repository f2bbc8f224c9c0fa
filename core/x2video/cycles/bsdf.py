"""Principled BSDF materials in Blender for the procedural room's `Material`s (`x2video.cycles.room`): the
rasterizer's pattern as a texture, metal finishes, glass, lacquer and emission.
"""
from __future__ import annotations

import bpy
import numpy as np

from x2video.cycles.passes import set_input
from x2video.cycles.variety import apply_surface
from x2video.procedural.materials import Material

#: metal finishes: (caption word, linear base colour, roughness range)
METALS = (("brushed steel", (0.56, 0.57, 0.58), (0.25, 0.4)), ("brass", (0.91, 0.78, 0.42), (0.1, 0.3)),
          ("chrome", (0.55, 0.56, 0.57), (0.0, 0.06)), ("copper", (0.95, 0.64, 0.54), (0.1, 0.3)))


def principled(name: str) -> tuple["bpy.types.Material", "bpy.types.ShaderNode"]:
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    return mat, bsdf


def _pattern(mat, bsdf, m: Material) -> None:
    """Drive Base Color by a texture standing in for the rasterizer's pattern (same period and contrast)."""
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    lo = [float(c) * (1 - m.contrast) for c in m.albedo] + [1.0]
    hi = [min(1.0, float(c) * (1 + m.contrast)) for c in m.albedo] + [1.0]
    coord = nodes.new("ShaderNodeTexCoord")
    if m.pattern in ("planks", "tiles"):
        tex = nodes.new("ShaderNodeTexBrick")
        tex.inputs["Color1"].default_value, tex.inputs["Color2"].default_value = lo, hi
        tex.inputs["Mortar"].default_value = [float(c) * 0.6 for c in m.albedo] + [1.0]
        tex.inputs["Scale"].default_value = 1.0 / max(m.scale, 0.02)
        tex.inputs["Mortar Size"].default_value = 0.01 if m.pattern == "planks" else 0.02
        if m.pattern == "planks":
            tex.inputs["Brick Width"].default_value, tex.inputs["Row Height"].default_value = 4.0, 1.0
        links.new(coord.outputs["Object"], tex.inputs["Vector"])
        links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        return
    if m.pattern == "stripes":
        tex = nodes.new("ShaderNodeTexWave")
        tex.inputs["Scale"].default_value = 1.0 / max(m.scale, 0.02)
        fac = tex.outputs["Fac"]
    else:  # noise, grain, veins
        tex = nodes.new("ShaderNodeTexNoise")
        tex.inputs["Scale"].default_value = 1.0 / max(m.scale, 0.02) * (3.0 if m.pattern == "grain" else 1.0)
        tex.inputs["Detail"].default_value = 6.0 if m.pattern == "veins" else 3.0
        fac = tex.outputs["Fac"]
    links.new(coord.outputs["Object"], tex.inputs["Vector"])
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color, ramp.color_ramp.elements[1].color = lo, hi
    links.new(fac, ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])


def make_material(m: Material, name: str, *, roughness: float | None = None, metal: int | None = None,
                  glass: bool = False, lacquer: float | None = None, emit_gain: float = 1.0,
                  surface: tuple[str, float, float, float] | None = None) -> "bpy.types.Material":
    """One Principled BSDF material for our `Material` (or a metal finish, glass or a dark lacquer of grey
    `lacquer` standing in for it); `emit_gain` scales its emission; `surface` (`x2video.cycles.variety`) textures its
    albedo, roughness and bump instead of the rasterizer's pattern."""
    mat, bsdf = principled(name)
    if lacquer is not None:
        bsdf.inputs["Base Color"].default_value = (*(float(lacquer) * np.asarray(m.albedo) / max(float(np.max(m.albedo)), 1e-3)), 1.0)
        bsdf.inputs["Roughness"].default_value = float(m.roughness if roughness is None else roughness)
        return mat
    if metal is not None:
        _, colour, (r0, r1) = METALS[metal]
        bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
        bsdf.inputs["Metallic"].default_value = 1.0
        bsdf.inputs["Roughness"].default_value = float(np.mean([r0, r1])) if roughness is None else roughness
        return mat
    bsdf.inputs["Base Color"].default_value = (*map(float, m.albedo), 1.0)
    bsdf.inputs["Roughness"].default_value = float(m.roughness if roughness is None else roughness)
    bsdf.inputs["Metallic"].default_value = float(m.metallic)
    if glass:
        set_input(bsdf, ("Transmission Weight", "Transmission"), 1.0)
        bsdf.inputs["Roughness"].default_value = 0.0
        bsdf.inputs["Base Color"].default_value = (0.95, 0.97, 0.96, 1.0)
        return mat
    if surface is not None:
        apply_surface(mat, bsdf, np.asarray(m.albedo, float), float(m.roughness if roughness is None else roughness), surface)
    elif m.pattern != "flat" and m.contrast > 0:
        _pattern(mat, bsdf, m)
    if float(np.max(m.emission)) > 0:
        set_input(bsdf, ("Emission Color", "Emission"), (*map(float, m.emission / max(float(np.max(m.emission)), 1e-6)), 1.0))
        set_input(bsdf, ("Emission Strength",), float(np.max(m.emission)) * float(emit_gain))
    return mat
