"""A procedural interior room for a seed: shell with openings, styled materials, furniture placed without overlaps, lights, captions."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from x2video.procedural import furniture as F
from x2video.procedural.geometry import Part, SceneObject, rotate_y
from x2video.procedural.lighting import MOODS, Lighting, ceiling_on, light_points_for, sun_for, white_balance
from x2video.procedural.materials import Material, emissive, sample_material, sky
from x2video.procedural.room import WALL_T, Opening, door_parts, sky_part, wall_box, wall_frame, wall_parts, window_centre, window_frame_parts

#: style -> colours its materials are drawn from (metals keep their own tints)
STYLES: dict[str, tuple[str, ...]] = {
    "modern": ("white", "light grey", "grey", "dark grey", "black", "blue", "teal", "beige", "silver", "light brown", "brown"),
    "scandinavian": ("white", "cream", "light grey", "beige", "light brown", "light blue", "green", "grey", "silver", "brass"),
    "rustic": ("brown", "dark brown", "cream", "beige", "burgundy", "olive", "orange", "light brown", "copper", "dark green"),
    "industrial": ("dark grey", "black", "grey", "brown", "burgundy", "silver", "copper", "dark brown", "light grey"),
    "classic": ("burgundy", "dark green", "dark blue", "cream", "brown", "brass", "beige", "white", "dark brown"),
    "eclectic": ("red", "yellow", "teal", "pink", "purple", "orange", "green", "blue", "white", "light brown", "brass", "dark brown"),
}
ROOM_TYPES = ("living room", "bedroom", "dining room", "study")
#: (category, how many (lo, hi), where): wall = against a wall, centre = free-standing
ROOM_ITEMS: dict[str, list[tuple[str, tuple[int, int], str]]] = {
    "living room": [("sofa", (1, 1), "wall"), ("cabinet", (1, 1), "wall+tv"), ("armchair", (0, 2), "wall"), ("coffee table", (1, 1), "centre+rug"),
                    ("bookshelf", (0, 1), "wall"), ("floor lamp", (1, 1), "wall"), ("potted plant", (1, 2), "wall"), ("painting", (1, 2), "hang")],
    "bedroom": [("bed", (1, 1), "wall+nightstands"), ("wardrobe", (1, 1), "wall"), ("cabinet", (0, 1), "wall"), ("armchair", (0, 1), "wall"),
                ("rug", (0, 1), "centre"), ("potted plant", (0, 1), "wall"), ("floor lamp", (0, 1), "wall"), ("painting", (1, 2), "hang")],
    "dining room": [("dining table", (1, 1), "centre+chairs+rug"), ("cabinet", (1, 2), "wall"), ("bookshelf", (0, 1), "wall"),
                    ("potted plant", (1, 2), "wall"), ("floor lamp", (0, 1), "wall"), ("painting", (1, 2), "hang")],
    "study": [("desk", (1, 1), "wall+chair+lamp"), ("bookshelf", (1, 2), "wall"), ("armchair", (0, 1), "wall"), ("floor lamp", (1, 1), "wall"),
              ("cabinet", (0, 1), "wall"), ("potted plant", (0, 1), "wall"), ("rug", (0, 1), "centre"), ("painting", (0, 2), "hang")],
}


@dataclass
class Scene:
    """Everything the renderer and the camera need about one room."""

    seed: int
    width: float
    depth: float
    height: float
    room_type: str
    style: str
    materials: list[Material]
    objects: list[SceneObject]
    lighting: Lighting
    openings: list[Opening]
    #: (x0, z0, x1, z1) floor rectangles the camera must keep out of
    obstacles: list[tuple[float, float, float, float]] = field(default_factory=list)
    #: candidate camera starts (corners and wall midpoints kept free of furniture)
    starts: list[np.ndarray] = field(default_factory=list)

    @property
    def caption(self) -> str:
        return f"{_article(self.style)} {self.style} {self.room_type} {MOODS[self.lighting.mood].phrase}"

    def object_captions(self) -> dict[int, str]:
        return {o.id: o.caption for o in self.objects}


def _article(word: str) -> str:
    return "an" if word[:1].lower() in "aeiou" else "a"


def _caption(m: Material, category: str, plural: bool = False) -> str:
    text = f"{m.describe()} {category}"
    return text if plural else f"{_article(text)} {text}"


class _Builder:
    """Accumulates materials and objects; each object gets the next id (0 stays 'nothing')."""

    def __init__(self, rng: np.random.Generator, palette: tuple[str, ...]):
        self.rng, self.palette = rng, palette
        self.materials: list[Material] = []
        self.objects: list[SceneObject] = []

    def material(self, m: Material) -> int:
        self.materials.append(m)
        return len(self.materials) - 1

    def draw(self, families: tuple[str, ...], colours: tuple[str, ...] | None = None, pattern: str | None = None) -> Material:
        fam = str(self.rng.choice(families))
        return sample_material(self.rng, fam, colours or self.palette, pattern)

    def add(self, category: str, caption: str, parts: list[Part], blocks: bool = True) -> SceneObject:
        obj = SceneObject(len(self.objects) + 1, category, caption, parts, blocks)
        self.objects.append(obj)
        return obj

    def add_design(self, d: F.Design, turns: int, origin: np.ndarray, main: Material | None = None,
                   accent: Material | None = None) -> tuple[SceneObject, Material]:
        colours = d.extra.get("colours")
        main = main or self.draw(d.main, colours)
        accent = accent or self.draw(d.accent)
        mi, ai = self.material(main), self.material(accent)
        parts = []
        for kind, lo, hi, slot, shadow in d.parts:
            wlo, whi = rotate_y(np.array(lo), np.array(hi), turns, origin)
            parts.append(Part(kind, wlo, whi, mi if slot == "main" else ai, shadow))
        if d.caption:
            words = {"main": main.describe(), "accent": accent.describe()}
            text = d.caption.format(main_=words["main"], accent_=words["accent"], **{k: f"{_article(v)} {v}" for k, v in words.items()})
        else:
            text = _caption(main, d.category)
        return self.add(d.category, text, parts, d.blocks_camera), main


def _turn(v: np.ndarray, turns: int) -> np.ndarray:
    """Rotate a vector by quarter turns about +y (the same rotation as `rotate_y`)."""
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][turns % 4]
    return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])


def _rect(d: F.Design, turns: int, origin: np.ndarray) -> tuple[float, float, float, float]:
    lo, hi = rotate_y(np.array([-d.width / 2, 0, -d.depth / 2]), np.array([d.width / 2, d.height, d.depth / 2]), turns, origin)
    return lo[0], lo[2], hi[0], hi[2]


def _overlaps(r, rects, margin: float) -> bool:
    return any(r[0] < q[2] + margin and q[0] < r[2] + margin and r[1] < q[3] + margin and q[1] < r[3] + margin for q in rects)


def _inside(r, w: float, d: float) -> bool:
    return r[0] >= 0 and r[1] >= 0 and r[2] <= w and r[3] <= d


def generate_scene(seed: int) -> Scene:
    """The room for `seed` (deterministic): size, openings, materials, furniture, lights and captions."""
    rng = np.random.default_rng([seed, 3])
    w, d, h = rng.uniform(3.0, 8.0), rng.uniform(3.0, 8.0), rng.uniform(2.5, 3.2)
    style, room_type = str(rng.choice(list(STYLES))), str(rng.choice(ROOM_TYPES))
    mood = MOODS[str(rng.choice(list(MOODS)))]
    b = _Builder(rng, STYLES[style])

    # --- openings: one door, one or two windows on other walls
    walls = [int(i) for i in rng.permutation(4)]
    openings = []
    dl = wall_frame(walls[0], w, d)[3]
    du = rng.uniform(0.3, dl - 1.2)
    openings.append(Opening(walls[0], du, du + 0.9, 0.0, 2.1, "door"))
    for wall in walls[1:1 + int(rng.integers(1, 3))]:
        length = wall_frame(wall, w, d)[3]
        ww = min(rng.uniform(1.0, 2.2), length - 1.0)
        u0 = rng.uniform(0.5, length - 0.5 - ww)
        sill = rng.uniform(0.7, 1.0)
        openings.append(Opening(wall, u0, u0 + ww, sill, min(h - 0.3, sill + rng.uniform(1.2, 1.6)), "window"))

    # --- shell
    floor_m = b.draw(("wood", "wood", "ceramic", "stone", "concrete", "fabric"), None)
    if floor_m.family == "wood":
        floor_m.pattern, floor_m.scale, floor_m.contrast = "planks", rng.uniform(0.12, 0.22), 0.1
    elif floor_m.family == "ceramic":
        floor_m.pattern, floor_m.scale, floor_m.contrast = "tiles", rng.uniform(0.3, 0.6), 0.06
    wall_m = b.draw(("painted",), ("white", "cream", "light grey", "beige", "light blue", "grey", "green", "pink", "yellow"))
    if rng.random() < 0.2:
        wall_m.pattern, wall_m.scale, wall_m.contrast = "stripes", rng.uniform(0.08, 0.2), 0.08
    ceil_m = sample_material(rng, "painted", ("white", "cream"), "flat")
    fi, wi, ci = b.material(floor_m), b.material(wall_m), b.material(ceil_m)
    b.add("floor", _caption(floor_m, "floor"), [Part("box", (-WALL_T, -WALL_T, -WALL_T), (w + WALL_T, 0, d + WALL_T), fi)], False)
    b.add("walls", _caption(wall_m, "walls", plural=True), [p for k in range(4) for p in wall_parts(k, w, d, h, openings, wi)], False)
    b.add("ceiling", _caption(ceil_m, "ceiling"), [Part("box", (-WALL_T, h, -WALL_T), (w + WALL_T, h + WALL_T, d + WALL_T), ci)], False)
    frame_m = sample_material(rng, "painted", ("white", "black", "dark grey", "cream"), "flat")
    sky_i = b.material(sky(np.array(mood.sky, np.float32)))
    fri = b.material(frame_m)
    door_m = b.draw(("wood", "painted"))
    handle_i = b.material(sample_material(rng, "metal", ("silver", "brass", "black")))
    windows = []
    for op in openings:
        if op.kind == "door":
            b.add("door", _caption(door_m, "door"), door_parts(op, w, d, b.material(door_m), handle_i), False)
        else:
            b.add("window", _caption(frame_m, "window frame"), window_frame_parts(op, w, d, fri) + [sky_part(op, w, d, sky_i)], False)
            windows.append(window_centre(op, w, d))

    # --- keep-out zones: in front of the door, a free camera start, windows for tall furniture
    zones = []
    o, a, n, _ = wall_frame(openings[0].wall, w, d)
    p0, p1 = o + a * (openings[0].u0 - 0.2), o + a * (openings[0].u1 + 0.2) + n * 1.2
    zones.append((min(p0[0], p1[0]), min(p0[2], p1[2]), max(p0[0], p1[0]), max(p0[2], p1[2])))
    inset = 0.6  # camera starts: corners and wall midpoints, this far from the walls
    cands = [np.array([x, 0, z]) for x in (inset, w / 2, w - inset) for z in (inset, d / 2, d - inset) if not (x == w / 2 and z == d / 2)]
    corners = [c for c in cands if c[0] != w / 2 and c[2] != d / 2]
    mids = [c for c in cands if c[0] == w / 2 or c[2] == d / 2]
    pool = corners if rng.random() < 0.75 else mids  # corners see the room along its diagonal: favour them
    start = pool[int(rng.integers(len(pool)))]
    zones.append((start[0] - 0.55, start[2] - 0.55, start[0] + 0.55, start[2] + 0.55))
    win_zones = []
    for op in openings[1:]:
        o, a, n, _ = wall_frame(op.wall, w, d)
        p0, p1 = o + a * (op.u0 - 0.1), o + a * (op.u1 + 0.1) + n * 0.9
        win_zones.append(((min(p0[0], p1[0]), min(p0[2], p1[2]), max(p0[0], p1[0]), max(p0[2], p1[2])), op.y0))

    occupied: list[tuple[float, float, float, float]] = []
    for op in openings[1:]:  # curtains beside some windows (before furniture, which then keeps clear of them)
        o, a, n, length = wall_frame(op.wall, w, d)
        pw = rng.uniform(0.25, 0.45)
        if rng.random() > 0.6 or op.u0 - pw < 0.05 or op.u1 + pw > length - 0.05:
            continue
        cm = b.draw(("fabric",), None, str(rng.choice(["flat", "flat", "stripes", "noise"])))
        ci_ = b.material(cm)
        top = min(h - 0.05, op.y1 + 0.25)
        parts = []
        for u0, u1 in ((op.u0 - pw, op.u0 + 0.06), (op.u1 - 0.06, op.u1 + pw)):
            lo, hi = wall_box(op.wall, w, d, u0, u1, 0.02, top, 0.03, 0.11)
            parts.append(Part("box", lo, hi, ci_))
            occupied.append((lo[0], lo[2], hi[0], hi[2]))
        b.add("curtains", _caption(cm, "curtains", plural=True), parts, False)
    lamp_bulbs: list[np.ndarray] = []
    lamp_objs: list[tuple[SceneObject, Material]] = []

    def blocked(r, height: float, margin: float) -> bool:
        if not _inside(r, w, d) or _overlaps(r, occupied, margin) or _overlaps(r, zones, 0.0):
            return True
        return any(height > sill - 0.05 and _overlaps(r, [z], 0.0) for z, sill in win_zones)

    def place_wall(des: F.Design, tries: int = 40):
        for _ in range(tries):
            wall = int(rng.integers(4))
            o, a, n, length = wall_frame(wall, w, d)
            if length < des.width + 0.1:
                continue
            u = rng.uniform(des.width / 2 + 0.02, length - des.width / 2 - 0.02)
            turns = [0, 3, 2, 1][wall]
            origin = o + a * u + n * (des.depth / 2 + 0.02)
            r = _rect(des, turns, origin)
            if not blocked(r, des.height, 0.08):
                return turns, origin, r
        return None

    def place_centre(des: F.Design, pad: float, tries: int = 40):
        for _ in range(tries):
            turns = int(rng.integers(4))
            origin = np.array([rng.uniform(1.0, w - 1.0), 0.0, rng.uniform(1.0, d - 1.0)])
            r = _rect(des, turns, origin)
            rp = (r[0] - pad, r[1] - pad, r[2] + pad, r[3] + pad)
            if not blocked(rp, des.height, 0.5):
                return turns, origin, r
        return None

    def put(des: F.Design, turns: int, origin: np.ndarray, r, main: Material | None = None) -> SceneObject:
        obj, m = b.add_design(des, turns, origin, main)
        if des.blocks_camera:
            occupied.append(r)
        if des.bulb is not None:
            lo, _ = rotate_y(np.array(des.bulb), np.array(des.bulb), turns, origin)
            lamp_bulbs.append(lo)
            lamp_objs.append((obj, m))
        return obj

    def put_on(des: F.Design, turns: int, origin: np.ndarray, y: float, main: Material | None = None) -> None:
        put(des, turns, origin + np.array([0, y, 0]), None, main)

    def put_rug(cx: float, cz: float, sx: float, sz: float) -> None:
        des = F.Design("rug", [F._b(-sx / 2, 0, -sz / 2, sx / 2, 0.012, sz / 2, shadow=False)], sx, sz, 0.012, ("fabric",), blocks_camera=False)
        lo = np.array([cx - sx / 2, cz - sz / 2, cx + sx / 2, cz + sz / 2])
        if lo[0] > 0.05 and lo[1] > 0.05 and lo[2] < w - 0.05 and lo[3] < d - 0.05:
            b.add_design(des, 0, np.array([cx, 0.0, cz]), b.draw(("fabric",), None, str(rng.choice(["flat", "stripes", "noise"]))))

    for cat, (lo_n, hi_n), where in ROOM_ITEMS[room_type]:
        for _ in range(int(rng.integers(lo_n, hi_n + 1))):
            des = F.CATEGORIES[cat](rng)
            if where == "hang":
                wall = int(rng.integers(4))
                o, a, n, length = wall_frame(wall, w, d)
                u = rng.uniform(des.width / 2 + 0.3, length - des.width / 2 - 0.3)
                y = rng.uniform(1.3, min(1.7, h - des.height - 0.2))
                clash = any(op.wall == wall and op.u0 - 0.1 < u + des.width / 2 and u - des.width / 2 < op.u1 + 0.1 for op in openings)
                if not clash and length > des.width + 0.8:
                    put(des, [0, 3, 2, 1][wall], o + a * u + n * 0.025 + np.array([0, y, 0]), None)
                continue
            if where.startswith("centre"):
                pad = 0.65 if "chairs" in where else 0.0
                got = place_centre(des, pad)
                if got is None:
                    continue
                turns, origin, r = got
                if cat == "rug":
                    put_rug(origin[0], origin[2], r[2] - r[0], r[3] - r[1])
                    continue
                put(des, turns, origin, r)
                if cat == "dining table" and rng.random() < 0.5:
                    put_on(F.vase(rng), turns, origin, des.height)
                if "chairs" in where:
                    chair_main = b.draw(F.chair(rng).main)
                    long_x = (r[2] - r[0]) >= (r[3] - r[1])
                    span = (r[2] - r[0]) if long_x else (r[3] - r[1])
                    k = 2 if span > 1.5 else 1
                    for side in (-1, 1):
                        for i in range(k):
                            off = (i - (k - 1) / 2) * span / k
                            ch = F.chair(rng)
                            gap = ch.depth / 2 + 0.01  # chair pulled out just clear of the table edge
                            c = origin + (np.array([off, 0, side * ((r[3] - r[1]) / 2 + gap)]) if long_x
                                          else np.array([side * ((r[2] - r[0]) / 2 + gap), 0, off]))
                            t = (2 if side > 0 else 0) if long_x else (3 if side > 0 else 1)
                            put(ch, t, c, _rect(ch, t, c), chair_main)
                if "rug" in where or ("chairs" in where and rng.random() < 0.6):
                    put_rug(origin[0], origin[2], r[2] - r[0] + rng.uniform(1.0, 1.6), r[3] - r[1] + rng.uniform(1.0, 1.6))
                continue
            got = place_wall(des)
            if got is None:
                continue
            turns, origin, r = got
            put(des, turns, origin, r)
            fwd_v = _turn(np.array([0.0, 0.0, 1.0]), turns)  # the furniture's front direction in the world
            side_v = np.array([fwd_v[2], 0.0, -fwd_v[0]])
            if "tv" in where and des.height < 0.85:
                tvd = F.tv(rng)
                put_on(tvd, turns, origin - fwd_v * 0.05, des.height)
            elif cat == "cabinet" and rng.random() < 0.6:  # a vase on top, off centre
                put_on(F.vase(rng), turns, origin + side_v * rng.uniform(-0.3, 0.3) * des.width, des.height)
            if "nightstands" in where:
                for s in (-1, 1):
                    ns = F.nightstand(rng)
                    c = origin + side_v * s * (des.width / 2 + ns.width / 2 + 0.05) + fwd_v * (ns.depth / 2 - des.depth / 2)
                    rr = _rect(ns, turns, c)
                    if not blocked(rr, ns.height, 0.0):
                        put(ns, turns, c, rr)
                        if rng.random() < 0.8:
                            put_on(F.table_lamp(rng), turns, c, ns.height)
            if "chair" in where:
                ch = F.chair(rng)
                c = origin + fwd_v * (des.depth / 2 + ch.depth / 2 + 0.02)
                rr = _rect(ch, (turns + 2) % 4, c)
                if not blocked(rr, ch.height, 0.0):
                    put(ch, (turns + 2) % 4, c, rr)
            if "lamp" in where:
                put_on(F.table_lamp(rng), turns, origin + side_v * (des.width / 2 - 0.2), des.height)

    # --- ceiling lights (fixture objects whose underside glows) and lights for the mood
    n_ceil = 2 if max(w, d) > 5.5 else 1
    spots = []
    for i in range(n_ceil):
        c = np.array([w / 2, h, d / 2]) if n_ceil == 1 else (np.array([w * (1 + 2 * i) / 4, h, d / 2]) if w >= d else np.array([w / 2, h, d * (1 + 2 * i) / 4]))
        r = rng.uniform(0.18, 0.3)
        lit = ceiling_on(mood, len(lamp_bulbs))
        mat = emissive(np.ones(3), 3.0 if lit else 0.0, word="round", name="white")
        shade = Part("cylinder", c - np.array([r, 0.06, r]), c + np.array([r, 0, r]), b.material(mat), False)
        b.add("ceiling light", _caption(mat, "ceiling light"), [shade], False)
        spots.append(c - np.array([0, 0.2, 0]))
    points = light_points_for(mood, rng, ceiling_spots=spots, lamp_bulbs=lamp_bulbs, windows=windows)
    if mood.lamps:
        for (obj, m), p in zip(lamp_objs, [q for q in points if q.kind == "lamp"]):
            m.emission = (p.colour * 0.8).astype(np.float32)  # the shade glows in its bulb's colour
    lighting = Lighting(mood.name, points, sun_for(mood, rng, windows), np.array(mood.sky, np.float32), mood.target)
    white_balance(lighting)

    starts = [np.array([x, 1.7, z]) for x, z in [(c[0], c[2]) for c in cands]]
    obstacles = list(occupied)
    return Scene(seed, w, d, h, room_type, style, b.materials, b.objects, lighting, openings, obstacles,
                 [start + np.array([0, 1.7, 0])] + [s for s in starts if not np.allclose(s[[0, 2]], start[[0, 2]])])
