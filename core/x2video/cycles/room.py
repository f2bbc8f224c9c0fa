"""Build a procedural room (`x2video.procedural.scene.Scene`) in Blender for Cycles: meshes, Principled materials, lights, sky.

The scene description is the rasterizer's; what only a path tracer gives is added here, drawn
from a generator of its own so the room itself stays the same: glossy floors, metal objects
(brushed steel, brass, chrome), a wall mirror, glass panes in the windows, emissive lamp
shades and ceiling fixtures, area lights, window portals onto a sky, global illumination.
`extras_for(seed)` says which of these a room gets; at least a third of the rooms hold a metal
object and a glossy floor.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import bmesh
import bpy
import numpy as np

from x2video.cycles.bsdf import METALS, make_material, principled
from x2video.cycles.variety import Variety, add_backdrops, add_decor, bevel_box, decor_caption, decor_class, decor_material, variety_for
from x2video.procedural.geometry import Part, SceneObject
from x2video.procedural.room import WALL_T, wall_box, wall_frame
from x2video.procedural.scene import Scene

#: categories whose main material may turn into metal (furniture with large faces)
METAL_OK = ("cabinet", "coffee table", "dining table", "desk", "floor lamp", "table lamp", "bookshelf", "nightstand", "vase", "chair", "tv")


@dataclass
class Extras:
    """What a room gets beyond the rasterizer's scene (drawn per room seed, independent of the room)."""

    glossy_floor: float | None = None  # floor roughness when glossy
    metal_objects: list[tuple[int, int]] = field(default_factory=list)  # (object id, METALS index)
    mirror: bool = False
    glass: bool = False
    samples: int = 64
    #: (object id, base grey, roughness): dark glossy dielectrics (lacquer, black glass, polished stone)
    lacquer: list[tuple[int, float, float]] = field(default_factory=list)
    #: objects turned into clear glass (vases, table tops, lamps): glass that is not a window
    glass_objects: list[int] = field(default_factory=list)
    #: multiplier on every emissive material's strength (shades and fixtures from dim to glaring)
    emit_gain: float = 1.0
    #: generator v3's textures, decor, bevels, backdrops and large mirrors (None: a v2 room)
    variety: Variety | None = None


def extras_for(scene: Scene, seed: int, version: int = 3) -> Extras:
    """The path-traced additions of room `seed`: half the rooms glossy-floored and half with metal, drawn together
    so that at least a third hold both (P = 0.55 * 0.8 = 0.44 with the coupling below); from generator `version` 3
    on, `x2video.cycles.variety` too (its own random stream: the v2 draws stay as they were)."""
    rng = np.random.default_rng([seed, 0xC7C1E5])
    ex = Extras()
    both = rng.random() < 0.55
    if both or rng.random() < 0.3:
        ex.glossy_floor = float(rng.uniform(0.02, 0.18))
    cands = [o.id for o in scene.objects if o.category in METAL_OK]
    if cands and (both or rng.random() < 0.3):
        k = int(rng.integers(1, min(3, len(cands)) + 1))
        ex.metal_objects = [(int(i), int(rng.integers(len(METALS)))) for i in rng.choice(cands, k, replace=False)]
    ex.mirror = bool(rng.random() < 0.35)
    ex.glass = bool(rng.random() < 0.5)
    # a second stream, so that adding these left the draws above (and the rooms built before them) unchanged
    rng2 = np.random.default_rng([seed, 0xC7C1E6])
    metal = {i for i, _ in ex.metal_objects}
    free = [o.id for o in scene.objects if o.category in METAL_OK and o.id not in metal]
    if free and rng2.random() < 0.45:
        k = int(rng2.integers(1, min(3, len(free)) + 1))
        ex.lacquer = [(int(i), float(rng2.uniform(0.01, 0.2)), float(rng2.uniform(0.02, 0.2)))
                      for i in rng2.choice(free, k, replace=False)]
    free = [i for i in free if i not in {j for j, _, _ in ex.lacquer}]
    if free and rng2.random() < 0.35:
        ex.glass_objects = [int(i) for i in rng2.choice(free, int(rng2.integers(1, min(2, len(free)) + 1)), replace=False)]
    ex.emit_gain = float(np.exp(rng2.uniform(np.log(0.5), np.log(4.0))))
    if version >= 3:
        ex.variety = variety_for(scene, seed, first_id=max(o.id for o in scene.objects) + 2)  # +1: the mirror's id
    return ex


# ---------------------------------------------------------------------------------------------- meshes
def _add_part(bm: "bmesh.types.BMesh", part: Part, slot: int, bevel: float = 0.0) -> None:
    lo, hi = np.asarray(part.lo, float), np.asarray(part.hi, float)
    c, size = (lo + hi) / 2, np.maximum(hi - lo, 1e-4)
    # ours: y up; Blender: z up. (x, y, z)_ours -> (x, -z, y)_blender
    if part.kind == "box":
        geom = bmesh.ops.create_cube(bm, size=1.0)
        smooth = False
    elif part.kind == "cylinder":  # vertical (ours y) axis
        geom = bmesh.ops.create_cone(bm, cap_ends=True, segments=24, radius1=0.5, radius2=0.5, depth=1.0)
        smooth = True
    else:
        geom = bmesh.ops.create_uvsphere(bm, u_segments=24, v_segments=12, radius=0.5)
        smooth = True
    verts = geom["verts"]
    scale = (size[0], size[2], size[1])
    bmesh.ops.scale(bm, vec=scale, verts=verts)
    bmesh.ops.translate(bm, vec=(c[0], -c[2], c[1]), verts=verts)
    if part.kind == "box" and bevel > 0 and float(np.min(size)) > 4 * bevel:
        bevel_box(bm, verts, bevel)
        verts = [v for v in bm.verts if v.is_valid and not v.tag]
    faces = {f for v in verts for f in v.link_faces}
    for f in faces:
        f.material_index = slot
        # cylinder caps stay flat: only faces whose normal is horizontal are smoothed
        f.smooth = smooth and (part.kind == "sphere" or abs(f.normal.z) < 0.5)


def add_object(name: str, obj: SceneObject, mats: list, bevel: float = 0.0) -> "bpy.types.Object":
    """One Blender mesh object for `obj` (all its parts, box edges rounded by `bevel` metres), pass index = its id,
    one slot per material used."""
    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    slots: dict[int, int] = {}
    for part in obj.parts:
        slot = slots.setdefault(part.material, len(slots))
        for v in bm.verts:
            v.tag = True  # the parts before this one
        _add_part(bm, part, slot, bevel)
    bm.to_mesh(mesh)
    bm.free()
    for mi in slots:
        mesh.materials.append(mats[mi])
    ob = bpy.data.objects.new(name, mesh)
    ob.pass_index = int(obj.id)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def to_blender(p: np.ndarray) -> tuple[float, float, float]:
    """A point in our frame (y up) in Blender's (z up)."""
    return float(p[0]), float(-p[2]), float(p[1])


# ---------------------------------------------------------------------------------------------- lights
#: our point-light intensity I (irradiance I/d^2 at d metres, divided-by-pi convention) -> Blender watts
POINT_WATTS = 4.0 * np.pi**2
#: our sun intensity (irradiance, divided-by-pi) -> Blender's W/m^2
SUN_STRENGTH = np.pi


def add_lights(scene: Scene) -> list:
    """Cycles lights for the room's lighting: area lights under ceiling fixtures, point bulbs in lamps,
    portals in the windows with the sky as world light, and the sun. Returns the light objects."""
    lights = []
    for i, p in enumerate(scene.lighting.points):
        if p.kind == "window":
            continue  # the sky through the window portals lights the room instead
        if p.kind == "ceiling":
            data = bpy.data.lights.new(f"ceiling_{i}", "AREA")
            data.shape, data.size = "DISK", 0.4
            data.energy = float(p.intensity * POINT_WATTS * 1.5)
        else:
            data = bpy.data.lights.new(f"lamp_{i}", "POINT")
            data.shadow_soft_size = 0.05
            data.energy = float(p.intensity * POINT_WATTS)
        data.color = tuple(map(float, p.colour / max(float(np.max(p.colour)), 1e-6)))
        ob = bpy.data.objects.new(data.name, data)
        ob.location = to_blender(p.position)
        bpy.context.scene.collection.objects.link(ob)  # area lights face -z (down) by default
        lights.append(ob)
    sun = scene.lighting.sun
    if sun is not None:
        data = bpy.data.lights.new("sun", "SUN")
        data.energy = float(sun.intensity * SUN_STRENGTH)
        data.angle = np.radians(1.0)
        data.color = tuple(map(float, sun.colour / max(float(np.max(sun.colour)), 1e-6)))
        ob = bpy.data.objects.new("sun", data)
        d = to_blender(sun.direction)  # towards the sun; the light shines along its local -z
        ob.rotation_mode = "QUATERNION"
        from mathutils import Vector

        ob.rotation_quaternion = Vector(d).to_track_quat("Z", "Y")
        bpy.context.scene.collection.objects.link(ob)
        lights.append(ob)
    for op in scene.openings:
        if op.kind != "window":
            continue
        lo, hi = wall_box(op.wall, scene.width, scene.depth, op.u0, op.u1, op.y0, op.y1, -WALL_T, -WALL_T)
        o, a, n, _ = wall_frame(op.wall, scene.width, scene.depth)
        data = bpy.data.lights.new(f"portal_{op.wall}", "AREA")
        data.shape = "RECTANGLE"
        data.size, data.size_y = float(op.u1 - op.u0), float(op.y1 - op.y0)
        data.cycles.is_portal = True
        ob = bpy.data.objects.new(data.name, data)
        ob.location = to_blender((lo + hi) / 2)
        from mathutils import Vector

        # a portal emits along its local -z, into the room: -z must point along the inward normal n
        ob.rotation_mode = "QUATERNION"
        ob.rotation_quaternion = Vector(to_blender(-np.asarray(n))).to_track_quat("Z", "Y")
        bpy.context.scene.collection.objects.link(ob)
        lights.append(ob)
    return lights


def set_world(scene: Scene, strength: float = 1.0) -> None:
    """The sky seen through the windows and lighting the room through them: a horizon-to-zenith gradient."""
    world = bpy.data.worlds.new("sky")
    bpy.context.scene.world = world
    world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    bg = next(n for n in nodes if n.bl_idname == "ShaderNodeBackground")
    sky = np.asarray(scene.lighting.sky, float)
    coord, sep, ramp = nodes.new("ShaderNodeTexCoord"), nodes.new("ShaderNodeSeparateXYZ"), nodes.new("ShaderNodeValToRGB")
    links.new(coord.outputs["Generated"], sep.inputs[0])
    links.new(sep.outputs["Z"], ramp.inputs["Fac"])
    ramp.color_ramp.elements[0].position, ramp.color_ramp.elements[1].position = 0.5, 1.0
    ramp.color_ramp.elements[0].color = (*(sky * 1.1 + 0.05 * sky.mean()), 1.0)  # horizon: a little brighter, greyer
    ramp.color_ramp.elements[1].color = (*(sky * np.array([0.8, 0.9, 1.15])), 1.0)
    links.new(ramp.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = float(strength)


# ---------------------------------------------------------------------------------------------- the room
def mirror_object(scene: Scene, seed: int, next_id: int, frame_mat: int, large: bool = False) -> SceneObject | None:
    """A wall mirror (a thin box on a wall clear of openings; `large`: 1.4 to 2.4 m wide), or None when no wall has room."""
    rng = np.random.default_rng([seed, 0x1111])
    for wall in rng.permutation(4):
        o, a, n, length = wall_frame(int(wall), scene.width, scene.depth)
        wdt = float(rng.uniform(0.6, 1.2))
        if large:
            wdt *= 2.0
        if length < wdt + 1.0:
            continue
        u = float(rng.uniform(0.5, length - 0.5 - wdt))
        if any(op.wall == wall and op.u0 - 0.1 < u + wdt and u < op.u1 + 0.1 for op in scene.openings):
            continue
        y0 = float(rng.uniform(0.9, 1.2)) if not large else float(rng.uniform(0.3, 0.6))
        lo, hi = wall_box(int(wall), scene.width, scene.depth, u, u + wdt, y0, min(scene.height - 0.2, y0 + wdt * 1.3), 0.0, 0.02)
        return SceneObject(next_id, "mirror", "a wall mirror", [Part("box", lo, hi, frame_mat)], False)
    return None


def _class_of(scene: Scene, obj: SceneObject, extras: Extras) -> str:
    """The material class (`x2video.cycles.classes`) of `obj` as `build_room` builds it."""
    from x2video.cycles.classes import object_class

    return object_class(scene, obj, metal={i for i, _ in extras.metal_objects}, glossy_floor=extras.glossy_floor,
                        glass=set(extras.glass_objects), lacquer={i: r for i, _, r in extras.lacquer})


def build_room(scene: Scene, extras: Extras) -> dict:
    """Clear the Blender file and build `scene` with `extras`.
    Returns {'captions': {id: caption}, 'extras': summary, 'material_class': {id: class}}."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    metal_of = dict(extras.metal_objects)
    lacquer_of = {i: (grey, r) for i, grey, r in extras.lacquer}
    glass_ids = set(extras.glass_objects)
    variety = extras.variety
    bevel = variety.bevel if variety is not None else 0.0
    captions = {}
    classes: dict[int, str] = {}
    cache: dict[tuple, object] = {}

    def mat_for(mi: int, obj: SceneObject):
        m = scene.materials[mi]
        if m.sky:
            return None
        is_main = mi == obj.parts[0].material
        key: tuple = (mi,)
        kw: dict = {}
        if float(np.max(m.emission)) > 0:
            key, kw = (mi, "emit"), {"emit_gain": extras.emit_gain}
        elif obj.id in metal_of and is_main:
            key, kw = (mi, "metal", metal_of[obj.id]), {"metal": metal_of[obj.id]}
        elif obj.id in lacquer_of and is_main:
            key, kw = (mi, "lacquer", obj.id), {"lacquer": lacquer_of[obj.id][0], "roughness": lacquer_of[obj.id][1]}
        elif obj.id in glass_ids and is_main:
            key, kw = (mi, "glass"), {"glass": True}
        elif obj.category == "floor" and extras.glossy_floor is not None:
            key, kw = (mi, "gloss"), {"roughness": extras.glossy_floor}
        if variety is not None and mi in variety.surfaces and not ({"metal", "glass", "lacquer", "emit"} & set(map(str, key))):
            key, kw = (*key, "surface"), {**kw, "surface": variety.surfaces[mi]}
        if key not in cache:
            cache[key] = make_material(m, f"m{'_'.join(map(str, key))}", **kw)
        return cache[key]

    glass_mat = make_material(scene.materials[0], "glass", glass=True) if extras.glass else None
    objects = list(scene.objects)
    if extras.mirror:
        mirror = mirror_object(scene, scene.seed, max(o.id for o in objects) + 1, 0, large=variety is not None and variety.large_mirror)
        if mirror is not None:
            objects.append(mirror)
    mirror_mat = None
    for obj in objects:
        if obj.category == "mirror":
            mirror_mat, bsdf = principled("mirror")
            bsdf.inputs["Base Color"].default_value = (0.92, 0.92, 0.92, 1.0)
            bsdf.inputs["Metallic"].default_value, bsdf.inputs["Roughness"].default_value = 1.0, 0.0
            mats = [mirror_mat] * len(scene.materials)
            add_object(f"o{obj.id}_mirror", obj, mats)
        else:
            parts = [p for p in obj.parts if not scene.materials[p.material].sky]
            if not parts:
                continue
            kept = SceneObject(obj.id, obj.category, obj.caption, parts, obj.blocks_camera)
            mats: list = [None] * len(scene.materials)
            for p in parts:
                mats[p.material] = mat_for(p.material, obj)
            ob = add_object(f"o{obj.id}_{obj.category.replace(' ', '_')}", kept, mats,
                            bevel=bevel if obj.category not in ("floor", "wall", "ceiling", "window", "door") else 0.0)
            if any(not p.casts_shadow for p in parts) and obj.category not in ("window",):
                ob.visible_shadow = False  # lamp shades and fixtures around their own light
        caption = obj.caption
        if obj.id in metal_of:
            caption = f"a {METALS[metal_of[obj.id]][0]} {obj.category}"
        elif obj.id in glass_ids:
            caption = f"a glass {obj.category}"
        captions[obj.id] = caption
        classes[obj.id] = _class_of(scene, obj, extras)
    if glass_mat is not None:  # a pane in every window, in the wall's middle
        for op in scene.openings:
            if op.kind != "window":
                continue
            lo, hi = wall_box(op.wall, scene.width, scene.depth, op.u0, op.u1, op.y0, op.y1, -WALL_T * 0.55, -WALL_T * 0.45)
            pane = SceneObject(0, "glass", "", [Part("box", lo, hi, 0)], False)
            ob = add_object(f"pane_{op.wall}", pane, [glass_mat])
            ob.visible_shadow = False  # thin glass: let the sun and the sky in
    backdrops = 0
    if variety is not None:
        for d in variety.decor:
            add_decor(d, lambda d: decor_material(d, principled))
            captions[d.id] = decor_caption(d)
            classes[d.id] = decor_class(d)
        if variety.backdrop:
            backdrops = add_backdrops(scene, scene.seed, add_object)
    add_lights(scene)
    set_world(scene)
    windows = sum(op.kind == "window" for op in scene.openings)
    var = {**variety.summary(), "backdrops": backdrops} if variety is not None else None
    return {"captions": captions, "extras": {"windows": int(windows), "variety": var,"glossy_floor": extras.glossy_floor,
                                             "metal": [[i, METALS[k][0]] for i, k in extras.metal_objects],
                                             "mirror": bool(extras.mirror and mirror_mat is not None), "glass": extras.glass,
                                             "lacquer": [[i, g, r] for i, g, r in extras.lacquer],
                                             "glass_objects": list(extras.glass_objects), "emit_gain": extras.emit_gain},
            "material_class": {int(k): v for k, v in sorted(classes.items())}}
