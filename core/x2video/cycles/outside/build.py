"""What the outside scenes are built with: meshes (bevelled boxes, cylinders, frustums, spheres), Principled
materials that remember their class, objects with ids, coloured lights, and the camera move. Needs bpy."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import bmesh
import bpy
import numpy as np
from mathutils import Matrix

from x2video.cycles.classes import classify
from x2video.cycles.passes import set_input
from x2video.procedural.camera import look_along

Vec = tuple[float, float, float]


@dataclass
class SceneSpec:
    """What a scene module's ``build`` returns besides the Blender objects it made."""

    caption: str
    #: u in [0, 1] over the shot -> (camera location, point looked at), Blender world (z up), metres
    camera: Callable[[float], tuple[Vec, Vec]]
    fov_y_deg: float = 55.0


@dataclass
class Builder:
    """Keeps the ids, captions, material records and classes of a scene being built."""

    captions: dict[int, str] = field(default_factory=dict)
    classes: dict[int, str] = field(default_factory=dict)
    materials: dict[str, dict] = field(default_factory=dict)
    objects: dict[int, str] = field(default_factory=dict)  # id -> Blender object name
    next_id: int = 1

    # ------------------------------------------------------------------------------------- materials
    def material(self, name: str, base: Vec, roughness: float, *, metallic: float = 0.0, transmission: float = 0.0,
                 emission: Vec | None = None, strength: float = 0.0, specular: float | None = None) -> "bpy.types.Material":
        """A Principled BSDF material; its class is recorded under its name."""
        mat = bpy.data.materials.new(name)
        mat.use_nodes = True
        bsdf = principled(mat)
        bsdf.inputs["Base Color"].default_value = (*base, 1.0)
        bsdf.inputs["Roughness"].default_value = float(roughness)
        bsdf.inputs["Metallic"].default_value = float(metallic)
        if transmission:
            set_input(bsdf, ("Transmission Weight", "Transmission"), float(transmission))
        if specular is not None:
            set_input(bsdf, ("Specular IOR Level", "Specular"), float(specular))
        if emission is not None and strength > 0:
            set_input(bsdf, ("Emission Color", "Emission"), (*emission, 1.0))
            set_input(bsdf, ("Emission Strength",), float(strength))
        cls = classify(roughness=roughness, metallic=metallic, transmission=transmission,
                       emission=strength * max(emission) if emission is not None else 0.0)
        self.materials[name] = {"class": cls, "base_color": [round(float(c), 4) for c in base], "roughness": float(roughness),
                                "metallic": float(metallic), "transmission": float(transmission),
                                "emission": float(strength) if emission is not None else 0.0, "objects": []}
        return mat

    def textured(self, mat: "bpy.types.Material", kind: str, c1: Vec, c2: Vec, *, scale: float = 5.0, mortar: Vec | None = None,
                 brick: tuple[float, float] = (0.5, 0.25), mortar_size: float = 0.015) -> "bpy.types.Material":
        """Drive Base Color by a Brick (tiles, planks), Wave (wood grain) or Noise (stone) texture in object space."""
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        bsdf = principled(mat)
        coord = nodes.new("ShaderNodeTexCoord")
        if kind == "brick":
            tex = nodes.new("ShaderNodeTexBrick")
            tex.inputs["Color1"].default_value, tex.inputs["Color2"].default_value = (*c1, 1.0), (*c2, 1.0)
            tex.inputs["Mortar"].default_value = (*(mortar or tuple(0.6 * c for c in c1)), 1.0)
            tex.inputs["Scale"].default_value = scale
            tex.inputs["Mortar Size"].default_value = mortar_size
            tex.inputs["Brick Width"].default_value, tex.inputs["Row Height"].default_value = brick
            links.new(coord.outputs["Object"], tex.inputs["Vector"])
            links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        else:
            tex = nodes.new("ShaderNodeTexWave" if kind == "wave" else "ShaderNodeTexNoise")
            tex.inputs["Scale"].default_value = scale
            if kind == "wave":
                tex.inputs["Distortion"].default_value = 6.0
            else:
                tex.inputs["Detail"].default_value = 8.0
            ramp = nodes.new("ShaderNodeValToRGB")
            ramp.color_ramp.elements[0].color, ramp.color_ramp.elements[1].color = (*c1, 1.0), (*c2, 1.0)
            links.new(coord.outputs["Object"], tex.inputs["Vector"])
            links.new(tex.outputs["Fac"], ramp.inputs["Fac"])
            links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
        self.materials[mat.name]["texture"] = kind
        self.materials[mat.name]["base_color"] = [round((a + b) / 2, 4) for a, b in zip(c1, c2)]
        return mat

    # ------------------------------------------------------------------------------------- objects
    def add(self, ob: "bpy.types.Object", caption: str, *mats: "bpy.types.Material", shadow: bool = True) -> "bpy.types.Object":
        """Give `ob` the next id (its pass index) and `mats`; its class is that of its first material, or
        ``emitter`` when any of them glows."""
        for m in mats:
            ob.data.materials.append(m)
        oid = self.next_id
        self.next_id += 1
        ob.pass_index = oid
        ob.visible_shadow = shadow
        self.captions[oid] = caption
        self.objects[oid] = ob.name
        cls = [self.materials[m.name]["class"] for m in mats]
        self.classes[oid] = "emitter" if "emitter" in cls else cls[0]
        for m in mats:
            self.materials[m.name]["objects"].append(oid)
        return ob


def principled(mat: "bpy.types.Material"):
    return next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")


# ----------------------------------------------------------------------------------------- meshes
def mesh_object(name: str, bm: "bmesh.types.BMesh", loc: Vec = (0, 0, 0), rot: Vec = (0, 0, 0), smooth: bool = False) -> "bpy.types.Object":
    if smooth:
        for f in bm.faces:
            f.smooth = len(f.verts) == 4  # the sides of cylinders and spheres; caps stay flat
    me = bpy.data.meshes.new(name)
    bm.to_mesh(me)
    bm.free()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    ob.location, ob.rotation_euler = loc, rot
    return ob


def box(name: str, size: Vec, loc: Vec, rot: Vec = (0, 0, 0), bevel: float = 0.0, segments: int = 3) -> "bpy.types.Object":
    """A box of `size` centred at `loc`, rotated by Euler `rot` (radians), its edges rounded by `bevel` metres."""
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=1.0, matrix=Matrix.Diagonal((*size, 1.0)))
    ob = mesh_object(name, bm, loc, rot)
    if bevel > 0:
        mod = ob.modifiers.new("bevel", "BEVEL")
        mod.width, mod.segments, mod.limit_method = bevel, segments, "ANGLE"
    return ob


def cylinder(name: str, radius: float, depth: float, loc: Vec, rot: Vec = (0, 0, 0), *, top: float | None = None,
             segments: int = 32) -> "bpy.types.Object":
    """A cylinder along its local z (a frustum with `top` radius), centred at `loc`."""
    bm = bmesh.new()
    bmesh.ops.create_cone(bm, cap_ends=True, cap_tris=False, segments=segments, radius1=radius,
                          radius2=radius if top is None else top, depth=depth)
    return mesh_object(name, bm, loc, rot, smooth=segments > 8)


def sphere(name: str, radius: float, loc: Vec, scale: Vec = (1, 1, 1)) -> "bpy.types.Object":
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16, radius=radius)
    bmesh.ops.scale(bm, vec=scale, verts=bm.verts)
    return mesh_object(name, bm, loc, smooth=True)


def plane(name: str, size: tuple[float, float], loc: Vec, rot: Vec = (0, 0, 0)) -> "bpy.types.Object":
    """A rectangle in its local xy plane (normal +z)."""
    bm = bmesh.new()
    bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=0.5, matrix=Matrix.Diagonal((size[0], size[1], 1.0, 1.0)))
    return mesh_object(name, bm, loc, rot)


# ----------------------------------------------------------------------------------------- lights, world
def area_light(name: str, size: tuple[float, float], loc: Vec, colour: Vec, energy: float, rot: Vec = (0, 0, 0)) -> "bpy.types.Object":
    """A rectangular area light shining down its local -z."""
    data = bpy.data.lights.new(name, "AREA")
    data.shape, data.size, data.size_y = "RECTANGLE", size[0], size[1]
    data.color, data.energy = colour, energy
    ob = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(ob)
    ob.location, ob.rotation_euler = loc, rot
    return ob


def point_light(name: str, loc: Vec, colour: Vec, energy: float, radius: float = 0.05) -> "bpy.types.Object":
    data = bpy.data.lights.new(name, "POINT")
    data.color, data.energy, data.shadow_soft_size = colour, energy, radius
    ob = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(ob)
    ob.location = loc
    return ob


def world(colour: Vec, strength: float, zenith: Vec | None = None) -> None:
    """The world: one colour, or a gradient from `colour` at the horizon to `zenith` overhead."""
    w = bpy.data.worlds.new("world")
    bpy.context.scene.world = w
    w.use_nodes = True
    nodes, links = w.node_tree.nodes, w.node_tree.links
    bg = next(n for n in nodes if n.bl_idname == "ShaderNodeBackground")
    bg.inputs["Strength"].default_value = float(strength)
    if zenith is None:
        bg.inputs["Color"].default_value = (*colour, 1.0)
        return
    coord, sep, ramp = nodes.new("ShaderNodeTexCoord"), nodes.new("ShaderNodeSeparateXYZ"), nodes.new("ShaderNodeValToRGB")
    links.new(coord.outputs["Generated"], sep.inputs[0])
    links.new(sep.outputs["Z"], ramp.inputs["Fac"])
    ramp.color_ramp.elements[0].position, ramp.color_ramp.elements[1].position = 0.5, 0.8
    ramp.color_ramp.elements[0].color, ramp.color_ramp.elements[1].color = (*colour, 1.0), (*zenith, 1.0)
    links.new(ramp.outputs["Color"], bg.inputs["Color"])


# ----------------------------------------------------------------------------------------- camera
def smooth(u: float) -> float:
    """Ease in and out: 0 -> 0, 1 -> 1, zero speed at both ends."""
    u = min(max(u, 0.0), 1.0)
    return u * u * (3 - 2 * u)


def lerp(a: Vec, b: Vec, u: float) -> Vec:
    return tuple(float(x + (y - x) * u) for x, y in zip(a, b))  # type: ignore[return-value]


def look_at(loc: Vec, target: Vec) -> np.ndarray:
    """The 4x4 cam_to_world (Blender camera: looks down -z, +y up; world z up) at `loc` looking at `target`."""
    eye, tgt = np.asarray(loc, float), np.asarray(target, float)
    fwd = tgt - eye
    fwd /= np.linalg.norm(fwd)
    return look_along(eye, fwd, [0.0, 0.0, 1.0])


def camera_poses(spec: SceneSpec, num_frames: int) -> list[np.ndarray]:
    return [look_at(*spec.camera(t / max(num_frames - 1, 1))) for t in range(num_frames)]


def add_camera(mats: list[np.ndarray], fov_y_deg: float) -> "bpy.types.Object":
    """A camera keyed on every frame (frame t = matrix t), so the Vector pass has motion."""
    data = bpy.data.cameras.new("camera")
    data.sensor_fit = "VERTICAL"
    data.angle_y = math.radians(fov_y_deg)
    data.clip_start, data.clip_end = 0.05, 200.0
    ob = bpy.data.objects.new("camera", data)
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.scene.camera = ob
    for t, m in enumerate(mats):
        mw = Matrix(m.tolist())
        ob.location = mw.to_translation()
        ob.rotation_euler = mw.to_euler("XYZ", ob.rotation_euler)  # continuous with the previous frame's
        ob.keyframe_insert("location", frame=t)
        ob.keyframe_insert("rotation_euler", frame=t)
    return ob
