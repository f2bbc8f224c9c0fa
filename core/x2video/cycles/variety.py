"""Generator v3's variety for Cycles rooms: what professional interiors are full of and our v2 rooms lack.

- **Surfaces**: procedural textures from Blender's own nodes (no downloads) on albedo, roughness and
  bump at once: wood (wave rings), tiles (brick), marble (distorted wave veins), fabric (a fine weave
  of two waves), terrazzo (voronoi chips), plaster (noise). The AOVs follow the links, so the
  albedo and roughness channels hold the texture and the Normal pass the bump.
- **Decor** of more than boxes: tori, cones, icospheres, Blender's monkey and lathed vases on top of
  tables, desks and shelves, as metal, glass, glossy or matte pieces.
- **Bevelled furniture**: box parts get rounded edges (highlights run along them, as on real furniture).
- **Backdrops**: an emissive picture plane outside the windows (facades, foliage) instead of the sky.
- **Large wall mirrors**.

`variety_for(scene, seed)` draws these from a random stream of its own, so a v2 room (`Extras` alone)
stays what it was. Needs `bpy` only in the builders (`apply_surface`, `add_decor`, `add_backdrops`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from x2video.procedural.geometry import Part, SceneObject
from x2video.procedural.scene import Scene

#: the newest room generator (`x2video.cycles.room.extras_for`: 3 adds this module's variety); bpy-free, so a
#: process that only plans a build can read it without importing Blender
GENERATOR_VERSION = 3
SURFACES = ("wood", "tiles", "marble", "fabric", "terrazzo", "plaster")
#: which surfaces suit which object categories (others draw from all)
SURFACE_FOR = {"floor": ("wood", "tiles", "marble", "terrazzo"), "wall": ("plaster", "tiles", "wood", "marble"),
               "sofa": ("fabric",), "bed": ("fabric",), "armchair": ("fabric",), "rug": ("fabric",), "chair": ("wood", "fabric"),
               "dining table": ("wood", "marble"), "coffee table": ("wood", "marble", "terrazzo"), "desk": ("wood",),
               "cabinet": ("wood",), "bookshelf": ("wood",), "nightstand": ("wood", "marble")}
#: categories decor may stand on
HOSTS = ("dining table", "coffee table", "desk", "cabinet", "nightstand", "bookshelf", "tv stand", "sideboard")
SHAPES = ("torus", "cone", "icosphere", "monkey", "vase")
FINISHES = ("matte", "glossy", "metal", "glass")
#: decor caption nouns
NOUNS = {"torus": "ring sculpture", "cone": "cone", "icosphere": "ball", "monkey": "monkey figurine", "vase": "vase"}


@dataclass
class Decor:
    """One decor piece: shape, finish, linear colour, centre of its base (ours, y up), size (m), object id, host id."""

    shape: str
    finish: str
    colour: tuple[float, float, float]
    base: tuple[float, float, float]
    size: float
    id: int
    host: int
    roughness: float = 0.3


@dataclass
class Variety:
    """What a v3 room adds (see the module docstring)."""

    #: material index -> (surface kind, feature size in metres, contrast in [0, 1], roughness swing)
    surfaces: dict[int, tuple[str, float, float, float]] = field(default_factory=dict)
    decor: list[Decor] = field(default_factory=list)
    #: rounded edges of box parts, metres (0: sharp)
    bevel: float = 0.0
    backdrop: bool = False
    large_mirror: bool = False

    def summary(self) -> dict:
        return {"surfaces": sorted({k for k, *_ in self.surfaces.values()}), "bevel": round(self.bevel, 4),
                "decor": [[d.id, d.shape, d.finish] for d in self.decor], "backdrop": self.backdrop, "large_mirror": self.large_mirror}


def variety_for(scene: Scene, seed: int, first_id: int) -> Variety:
    """The v3 additions of room `seed` (decor ids from `first_id` up)."""
    rng = np.random.default_rng([seed, 0xC7C1E7])
    v = Variety()
    # textures on about 60 % of the materials the room's objects use, by their category
    used: dict[int, str] = {}
    for o in scene.objects:
        for p in o.parts:
            m = scene.materials[p.material]
            if not m.sky and float(np.max(m.emission)) <= 0 and m.metallic < 0.5:
                used.setdefault(p.material, o.category)
    for mi, cat in sorted(used.items()):
        if rng.random() < 0.6:
            kinds = SURFACE_FOR.get(cat, SURFACES)
            kind = str(kinds[int(rng.integers(len(kinds)))])
            scale = {"wood": 0.25, "tiles": 0.4, "marble": 0.5, "fabric": 0.02, "terrazzo": 0.05, "plaster": 0.3}[kind]
            v.surfaces[mi] = (kind, float(scale * rng.uniform(0.6, 1.6)), float(rng.uniform(0.2, 0.6)), float(rng.uniform(0.05, 0.3)))
    v.bevel = float(rng.uniform(0.005, 0.03)) if rng.random() < 0.7 else 0.0
    has_window = any(op.kind == "window" for op in scene.openings)
    v.backdrop = bool(has_window and rng.random() < 0.35)
    v.large_mirror = bool(rng.random() < 0.5)
    hosts = [o for o in scene.objects if o.category in HOSTS]
    nid = int(first_id)
    for host in rng.permutation(len(hosts))[: int(rng.integers(0, 4))] if hosts else []:
        h = hosts[int(host)]
        lo, hi = h.lo, h.hi
        foot = float(min(hi[0] - lo[0], hi[2] - lo[2]))
        if foot < 0.2 or hi[1] > 2.0:
            continue
        size = float(min(rng.uniform(0.12, 0.35), foot * 0.7))
        cx = float(rng.uniform(lo[0] + size / 2, hi[0] - size / 2)) if hi[0] - lo[0] > size else float((lo[0] + hi[0]) / 2)
        cz = float(rng.uniform(lo[2] + size / 2, hi[2] - size / 2)) if hi[2] - lo[2] > size else float((lo[2] + hi[2]) / 2)
        finish = str(FINISHES[int(rng.choice(4, p=[0.3, 0.25, 0.3, 0.15]))])
        colour = tuple(float(c) for c in rng.uniform(0.05, 0.85, 3))
        v.decor.append(Decor(str(SHAPES[int(rng.integers(len(SHAPES)))]), finish, colour, (cx, float(hi[1]), cz), size, nid, int(h.id),
                             float(rng.uniform(0.02, 0.35))))
        nid += 1
    return v


def decor_class(d: Decor) -> str:
    """The material class (`x2video.cycles.classes`) of a decor piece."""
    from x2video.cycles.classes import classify

    return {"metal": "metal", "glass": "glass"}.get(d.finish) or classify(roughness=d.roughness if d.finish == "glossy" else 0.7)


def decor_caption(d: Decor) -> str:
    word = {"metal": "metal", "glass": "glass", "glossy": "glazed", "matte": "matte"}[d.finish]
    return f"a {word} {NOUNS[d.shape]}"


# ---------------------------------------------------------------------------------------------- Blender builders
def apply_surface(mat, bsdf, albedo: np.ndarray, roughness: float, surface: tuple[str, float, float, float]) -> None:
    """Drive Base Color, Roughness and Normal (bump) of `bsdf` by one procedural texture of Blender's nodes."""
    kind, scale, contrast, swing = surface
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    coord = nodes.new("ShaderNodeTexCoord")
    vec = coord.outputs["Object"]
    a = np.asarray(albedo, float)
    lo = np.clip(a * (1 - contrast), 0, 1)
    hi = np.clip(a * (1 + contrast), 0, 1)
    bump_strength = 0.15
    if kind == "wood":
        tex = nodes.new("ShaderNodeTexWave")
        tex.wave_type = "RINGS"
        tex.inputs["Scale"].default_value = 1.0 / scale
        tex.inputs["Distortion"].default_value = 4.0
        tex.inputs["Detail"].default_value = 3.0
        fac = tex.outputs["Fac"]
    elif kind == "tiles":
        tex = nodes.new("ShaderNodeTexBrick")
        tex.inputs["Scale"].default_value = 1.0 / scale
        tex.inputs["Mortar Size"].default_value = 0.03
        tex.inputs["Brick Width"].default_value, tex.inputs["Row Height"].default_value = 1.0, 1.0
        tex.offset = 0.0
        tex.inputs["Color1"].default_value = (1, 1, 1, 1)
        tex.inputs["Color2"].default_value = (0.8, 0.8, 0.8, 1)
        tex.inputs["Mortar"].default_value = (0, 0, 0, 1)
        sep = nodes.new("ShaderNodeSeparateColor")
        links.new(tex.outputs["Color"], sep.inputs["Color"])
        fac = sep.outputs[0]
        bump_strength = 0.4
    elif kind == "marble":
        tex = nodes.new("ShaderNodeTexWave")
        tex.inputs["Scale"].default_value = 1.0 / scale
        tex.inputs["Distortion"].default_value = 12.0
        tex.inputs["Detail"].default_value = 8.0
        tex.inputs["Detail Scale"].default_value = 2.0
        fac = tex.outputs["Fac"]
        bump_strength = 0.03
    elif kind == "fabric":
        w1, w2 = nodes.new("ShaderNodeTexWave"), nodes.new("ShaderNodeTexWave")
        w2.bands_direction = "Y"
        for w in (w1, w2):
            w.inputs["Scale"].default_value = 1.0 / scale
            links.new(vec, w.inputs["Vector"])
        mul = nodes.new("ShaderNodeMath")
        mul.operation = "MULTIPLY"
        links.new(w1.outputs["Fac"], mul.inputs[0])
        links.new(w2.outputs["Fac"], mul.inputs[1])
        fac = mul.outputs["Value"]
        tex = None
        bump_strength = 0.3
    elif kind == "terrazzo":
        tex = nodes.new("ShaderNodeTexVoronoi")
        tex.inputs["Scale"].default_value = 1.0 / scale
        sep = nodes.new("ShaderNodeSeparateColor")
        links.new(tex.outputs["Color"], sep.inputs["Color"])
        fac = sep.outputs[1]
        bump_strength = 0.05
    else:  # plaster
        tex = nodes.new("ShaderNodeTexNoise")
        tex.inputs["Scale"].default_value = 1.0 / scale
        tex.inputs["Detail"].default_value = 8.0
        fac = tex.outputs["Fac"]
        bump_strength = 0.2
    if tex is not None:
        links.new(vec, tex.inputs["Vector"])
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (*map(float, lo), 1.0)
    ramp.color_ramp.elements[1].color = (*map(float, hi), 1.0)
    links.new(fac, ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    rmap = nodes.new("ShaderNodeMapRange")
    rmap.inputs["To Min"].default_value = float(np.clip(roughness - swing, 0.02, 1.0))
    rmap.inputs["To Max"].default_value = float(np.clip(roughness + swing, 0.02, 1.0))
    if kind in ("tiles", "fabric"):  # grout and weave gaps are the rough part
        rmap.inputs["To Min"].default_value, rmap.inputs["To Max"].default_value = rmap.inputs["To Max"].default_value, rmap.inputs["To Min"].default_value
    links.new(fac, rmap.inputs["Value"])
    links.new(rmap.outputs["Result"], bsdf.inputs["Roughness"])
    bump = nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = float(bump_strength)
    bump.inputs["Distance"].default_value = float(min(0.01, scale * 0.05))
    links.new(fac, bump.inputs["Height"])
    links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])


def bevel_box(bm, verts, offset: float) -> None:
    """Round the edges of the box made of `verts` by `offset` metres (2 segments)."""
    import bmesh

    edges = list({e for v in verts for e in v.link_edges})
    if edges and offset > 0:
        bmesh.ops.bevel(bm, geom=list(verts) + edges, offset=float(offset), segments=2, affect="EDGES", profile=0.5)


def _torus(bm, major: float, minor: float, n: int = 32, m: int = 12):
    """A torus around the vertical (Blender z) axis, centred at the origin; returns its verts."""
    rings = []
    for i in range(n):
        u = 2 * np.pi * i / n
        ring = []
        for j in range(m):
            w = 2 * np.pi * j / m
            r = major + minor * np.cos(w)
            ring.append(bm.verts.new((r * np.cos(u), r * np.sin(u), minor * np.sin(w))))
        rings.append(ring)
    for i in range(n):
        for j in range(m):
            a, b = rings[i][j], rings[(i + 1) % n][j]
            c, d = rings[(i + 1) % n][(j + 1) % m], rings[i][(j + 1) % m]
            f = bm.faces.new((a, b, c, d))
            f.smooth = True
    return [v for r in rings for v in r]


def _lathe(bm, profile: list[tuple[float, float]], n: int = 32):
    """A surface of revolution of (radius, height) points around Blender's z; returns its verts."""
    rings = [[bm.verts.new((r * np.cos(2 * np.pi * i / n), r * np.sin(2 * np.pi * i / n), z)) for i in range(n)] for r, z in profile]
    for k in range(len(rings) - 1):
        for i in range(n):
            f = bm.faces.new((rings[k][i], rings[k][(i + 1) % n], rings[k + 1][(i + 1) % n], rings[k + 1][i]))
            f.smooth = True
    bottom = bm.faces.new(list(reversed(rings[0])))
    bottom.smooth = False
    return [v for r in rings for v in r]


def add_decor(d: Decor, make_mat) -> "object":
    """One decor piece as a Blender object (pass index = its id), material from `make_mat(decor)`."""
    import bmesh
    import bpy
    from mathutils import Matrix

    bm = bmesh.new()
    s = d.size
    if d.shape == "torus":
        verts = _torus(bm, 0.35 * s, 0.12 * s)
        bmesh.ops.rotate(bm, verts=verts, cent=(0, 0, 0), matrix=Matrix.Rotation(np.pi / 2, 3, "X"))
        z0 = 0.47 * s
    elif d.shape == "cone":
        verts = bmesh.ops.create_cone(bm, cap_ends=True, segments=32, radius1=0.4 * s, radius2=0.0, depth=s)["verts"]
        z0 = 0.5 * s
    elif d.shape == "icosphere":
        verts = bmesh.ops.create_icosphere(bm, subdivisions=3, radius=0.45 * s)["verts"]
        z0 = 0.45 * s
    elif d.shape == "monkey":
        verts = bmesh.ops.create_monkey(bm)["verts"]
        bmesh.ops.scale(bm, vec=(0.4 * s, 0.4 * s, 0.4 * s), verts=verts)
        bmesh.ops.rotate(bm, verts=verts, cent=(0, 0, 0), matrix=Matrix.Rotation(np.pi / 2, 3, "X"))
        z0 = 0.35 * s
    else:  # vase
        prof = [(0.25 * s, 0.0), (0.38 * s, 0.25 * s), (0.3 * s, 0.6 * s), (0.15 * s, 0.85 * s), (0.2 * s, 1.0 * s)]
        verts = _lathe(bm, prof)
        z0 = 0.0
    for f in bm.faces:
        f.smooth = True
    x, y, z = d.base  # ours: y up -> Blender (x, -z, y)
    bmesh.ops.translate(bm, vec=(x, -z, y + z0 + 0.001), verts=verts)
    mesh = bpy.data.meshes.new(f"decor_{d.id}")
    bm.to_mesh(mesh)
    bm.free()
    mesh.materials.append(make_mat(d))
    ob = bpy.data.objects.new(f"o{d.id}_decor_{d.shape}", mesh)
    ob.pass_index = int(d.id)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def decor_material(d: Decor, principled) -> "object":
    """The Principled material of a decor piece (`principled(name)` -> (material, bsdf), `room._principled`)."""
    from x2video.cycles.passes import set_input

    mat, bsdf = principled(f"decor_{d.id}")
    bsdf.inputs["Base Color"].default_value = (*d.colour, 1.0)
    if d.finish == "metal":
        bsdf.inputs["Metallic"].default_value = 1.0
        bsdf.inputs["Roughness"].default_value = float(d.roughness * 0.6)
    elif d.finish == "glass":
        set_input(bsdf, ("Transmission Weight", "Transmission"), 1.0)
        bsdf.inputs["Roughness"].default_value = 0.0
        bsdf.inputs["Base Color"].default_value = (0.9, 0.95, 0.92, 1.0)
    elif d.finish == "glossy":
        bsdf.inputs["Roughness"].default_value = float(d.roughness)
    else:
        bsdf.inputs["Roughness"].default_value = 0.7
    return mat


def add_backdrops(scene: Scene, seed: int, add_object) -> int:
    """An emissive picture plane 1.5 m outside every window: a facade of lit and dark panes or foliage, as bright as the
    sky it hides (the room's daylight now comes from it). It casts no shadow, so the sun still shines in. `add_object` is
    `x2video.cycles.room.add_object` (passed in: room imports this module). Returns how many."""
    import bpy

    from x2video.procedural.room import WALL_T, wall_box

    rng = np.random.default_rng([seed, 0xBACD])
    sky = np.asarray(scene.lighting.sky, float)
    n_added = 0
    for op in scene.openings:
        if op.kind != "window":
            continue
        pad = 2.0
        lo, hi = wall_box(op.wall, scene.width, scene.depth, op.u0 - pad, op.u1 + pad, max(op.y0 - pad, -1.0), op.y1 + pad,
                          -WALL_T - 1.5, -WALL_T - 1.49)
        mat = bpy.data.materials.new(f"backdrop_{op.wall}")
        mat.use_nodes = True
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        for nd in list(nodes):
            nodes.remove(nd)
        out = nodes.new("ShaderNodeOutputMaterial")
        em = nodes.new("ShaderNodeEmission")
        coord = nodes.new("ShaderNodeTexCoord")
        if rng.random() < 0.5:  # facade: bricks of lit and dark windows
            tex = nodes.new("ShaderNodeTexBrick")
            tex.inputs["Scale"].default_value = float(rng.uniform(1.5, 3.0))
            tex.inputs["Color1"].default_value = (*(sky * 1.4), 1.0)
            tex.inputs["Color2"].default_value = (*(sky * 0.5), 1.0)
            tex.inputs["Mortar"].default_value = (*(sky * 0.8), 1.0)
            colour = tex.outputs["Color"]
        else:  # foliage: green noise against the sky
            tex = nodes.new("ShaderNodeTexNoise")
            tex.inputs["Scale"].default_value = float(rng.uniform(2.0, 6.0))
            tex.inputs["Detail"].default_value = 8.0
            ramp = nodes.new("ShaderNodeValToRGB")
            ramp.color_ramp.elements[0].color = (*(sky * np.array([0.3, 0.6, 0.25])), 1.0)
            ramp.color_ramp.elements[1].color = (*(sky * 1.2), 1.0)
            links.new(tex.outputs["Fac"], ramp.inputs["Fac"])
            colour = ramp.outputs["Color"]
        links.new(coord.outputs["Object"], tex.inputs["Vector"])
        links.new(colour, em.inputs["Color"])
        em.inputs["Strength"].default_value = 1.0
        links.new(em.outputs["Emission"], out.inputs["Surface"])
        ob = add_object(f"backdrop_{op.wall}", SceneObject(0, "backdrop", "", [Part("box", lo, hi, 0)], False), [mat])
        ob.visible_shadow = False
        n_added += 1
    return n_added
