"""A living room at night: a tall wall mirror (metallic 1, roughness 0), a glazed window onto a dark blue
night sky with lit city windows far away, warm lamps with glowing shades, a teal sofa turned off the
wall, a round black lacquer table on a chrome pedestal, a rug. The camera pans from the mirror to the
sofa and the window while drifting the other way."""
from __future__ import annotations

import math

import bpy
import numpy as np

from x2video.cycles.outside.build import Builder, SceneSpec, box, cylinder, lerp, plane, point_light, smooth, sphere, world

W, D, H = 5.0, 4.0, 2.6  # x in [-W/2, W/2], y in [-D/2, D/2], z in [0, H]
WIN = (-1.0, 1.0, 0.8, 2.2)  # window opening in the back wall: x0, x1, z0, z1
LAMP = (1.0, 0.55, 0.25)


def group(name: str, loc, rot_z: float) -> "bpy.types.Object":
    """An empty that parts are parented to, so that a piece of furniture turns as one."""
    ob = bpy.data.objects.new(name, None)
    bpy.context.scene.collection.objects.link(ob)
    ob.location, ob.rotation_euler = loc, (0, 0, rot_z)
    return ob


def build(b: Builder) -> SceneSpec:
    oak = b.textured(b.material("dark_oak_floor", (0.2, 0.12, 0.07), 0.3), "brick", (0.22, 0.13, 0.07), (0.16, 0.09, 0.05),
                     scale=1.0, mortar=(0.08, 0.05, 0.03), brick=(1.4, 0.18), mortar_size=0.004)
    wall = b.material("warm_grey_paint", (0.55, 0.5, 0.45), 0.85)
    ceiling = b.material("ceiling", (0.75, 0.73, 0.7), 0.9)
    mirror = b.material("mirror", (0.95, 0.95, 0.95), 0.0, metallic=1.0)
    frame_wood = b.material("black_wood", (0.04, 0.035, 0.03), 0.4)
    glass = b.material("window_glass", (0.95, 0.97, 0.96), 0.0, transmission=1.0)
    alu = b.material("window_frame", (0.15, 0.15, 0.16), 0.4, metallic=1.0)
    fabric = b.material("teal_velvet", (0.04, 0.19, 0.21), 0.9)
    mustard = b.material("mustard_linen", (0.6, 0.4, 0.06), 0.85)
    brass = b.material("brass", (0.9, 0.75, 0.4), 0.25, metallic=1.0)
    chrome = b.material("chrome", (0.55, 0.56, 0.57), 0.05, metallic=1.0)
    lacquer = b.material("black_lacquer", (0.02, 0.02, 0.025), 0.08)
    rug = b.textured(b.material("rug", (0.4, 0.12, 0.1), 0.95), "wave", (0.5, 0.14, 0.1), (0.25, 0.2, 0.3), scale=2.0)
    shade = b.material("lamp_shade", (0.9, 0.8, 0.65), 0.8, emission=LAMP, strength=4.0)
    ceramic = b.material("green_ceramic", (0.15, 0.35, 0.25), 0.15)
    building = b.material("building", (0.03, 0.03, 0.035), 0.9)
    city = [b.material(f"city_light_{k}", (0.8, 0.8, 0.8), 0.5, emission=c, strength=s)
            for k, (c, s) in enumerate((((1.0, 0.7, 0.35), 6.0), ((1.0, 0.85, 0.6), 4.0), ((0.7, 0.85, 1.0), 5.0)))]

    # --- the room: the back wall around a window opening
    b.add(box("floor", (W, D, 0.1), (0, 0, -0.05)), "a dark oak plank floor", oak)
    b.add(box("ceiling", (W, D, 0.1), (0, 0, H + 0.05)), "a ceiling", ceiling)
    b.add(box("wall_front", (W, 0.1, H), (0, -D / 2 - 0.05, H / 2)), "a warm grey wall", wall)
    b.add(box("wall_left", (0.1, D, H), (-W / 2 - 0.05, 0, H / 2)), "a warm grey wall", wall)
    b.add(box("wall_right", (0.1, D, H), (W / 2 + 0.05, 0, H / 2)), "a warm grey wall", wall)
    x0, x1, z0, z1 = WIN
    yw = D / 2 + 0.05
    b.add(box("wall_back_l", (x0 + W / 2, 0.1, H), ((x0 - W / 2) / 2, yw, H / 2)), "a warm grey wall", wall)
    b.add(box("wall_back_r", (W / 2 - x1, 0.1, H), ((x1 + W / 2) / 2, yw, H / 2)), "a warm grey wall", wall)
    b.add(box("wall_back_b", (x1 - x0, 0.1, z0), ((x0 + x1) / 2, yw, z0 / 2)), "a warm grey wall", wall)
    b.add(box("wall_back_t", (x1 - x0, 0.1, H - z1), ((x0 + x1) / 2, yw, (z1 + H) / 2)), "a warm grey wall", wall)
    pane = b.add(box("window_pane", (x1 - x0, 0.01, z1 - z0), ((x0 + x1) / 2, yw, (z0 + z1) / 2)), "a window pane", glass, shadow=False)
    pane.visible_shadow = False
    for j, (sx, sz, px, pz) in enumerate(((0.06, z1 - z0, x0 + 0.03, None), (0.06, z1 - z0, x1 - 0.03, None), (0.06, z1 - z0, 0.0, None),
                                          (x1 - x0, 0.06, 0.0, z0 + 0.03), (x1 - x0, 0.06, 0.0, z1 - 0.03))):
        b.add(box(f"window_frame_{j}", (sx, 0.08, sz), (px, yw - 0.02, (z0 + z1) / 2 if pz is None else pz), bevel=0.008),
              "a dark aluminium window frame", alu)
    # outside: dark towers with lit windows, far away, under a deep blue sky
    rng = np.random.default_rng(1234)
    for k in range(6):
        bx, bh = -30 + 12 * k + rng.uniform(-3, 3), rng.uniform(15, 40)
        by = 45 + rng.uniform(0, 20)
        b.add(box(f"tower_{k}", (8, 8, bh), (bx, by, bh / 2 - 10)), "a distant tower", building)
        for j in range(7):
            lx, lz = bx + rng.uniform(-3.2, 3.2), rng.uniform(-8, bh - 12)
            b.add(plane(f"city_{k}_{j}", (0.9, 0.6), (lx, by - 4.05, lz), (math.pi / 2, 0, 0)), "a lit window far away",
                  city[int(rng.integers(len(city)))])
    world((0.012, 0.018, 0.05), 1.0, zenith=(0.002, 0.003, 0.012))

    # --- the mirror on the left wall, in a black frame
    b.add(box("mirror_frame", (0.04, 1.12, 1.62), (-W / 2 + 0.02, 0.1, 1.35), bevel=0.015), "a black wooden mirror frame", frame_wood)
    b.add(box("mirror", (0.01, 1.0, 1.5), (-W / 2 + 0.045, 0.1, 1.35)), "a tall wall mirror", mirror)

    # --- a teal sofa on the right, turned 100 degrees, with a mustard cushion and brass legs
    g = group("sofa", (1.55, -0.45, 0.0), math.radians(-100))

    def part(ob, caption, mat):
        ob.parent = g
        return b.add(ob, caption, mat)

    part(box("sofa_base", (2.0, 0.9, 0.32), (0, 0, 0.28), bevel=0.06), "a teal velvet sofa", fabric)
    part(box("sofa_back", (2.0, 0.22, 0.5), (0, 0.36, 0.66), bevel=0.08), "the sofa's back", fabric)
    for s in (-1, 1):
        part(box(f"sofa_arm_{s}", (0.2, 0.9, 0.62), (s * 0.98, 0, 0.43), bevel=0.08), "a sofa arm", fabric)
        part(box(f"sofa_cushion_{s}", (0.86, 0.66, 0.14), (s * 0.44, -0.08, 0.5), bevel=0.06), "a sofa cushion", fabric)
        for t in (-1, 1):
            part(cylinder(f"sofa_leg_{s}_{t}", 0.02, 0.12, (s * 0.95, t * 0.38, 0.06), top=0.014, segments=12), "a brass sofa leg", brass)
    pillow = sphere("pillow", 0.2, (-0.6, 0.18, 0.72), (1.0, 0.4, 0.9))
    pillow.rotation_euler = (math.radians(-15), 0, math.radians(10))
    part(pillow, "a mustard linen cushion", mustard)

    # --- a round lacquer table on a chrome pedestal, a rug, a vase
    b.add(box("rug", (2.6, 1.8, 0.012), (0.5, -0.3, 0.006), (0, 0, math.radians(-10)), bevel=0.005), "a patterned rug", rug)
    b.add(cylinder("table_top", 0.45, 0.035, (0.45, -0.35, 0.42)), "a round black lacquer table", lacquer)
    b.add(cylinder("table_stem", 0.045, 0.38, (0.45, -0.35, 0.21), segments=24), "a chrome pedestal", chrome)
    b.add(cylinder("table_foot", 0.22, 0.02, (0.45, -0.35, 0.02)), "a chrome pedestal foot", chrome)
    b.add(cylinder("vase", 0.07, 0.25, (0.35, -0.3, 0.56), top=0.04, segments=24), "a green ceramic vase", ceramic)

    # --- warm lamps: a floor lamp by the sofa, a table lamp on a side table by the mirror
    fx, fy = 2.05, 1.3
    b.add(cylinder("floor_lamp_base", 0.15, 0.03, (fx, fy, 0.015)), "a brass floor lamp base", brass)
    b.add(cylinder("floor_lamp_pole", 0.012, 1.45, (fx, fy, 0.75), segments=12), "a brass floor lamp pole", brass)
    b.add(cylinder("floor_lamp_shade", 0.24, 0.32, (fx, fy, 1.6), top=0.16, segments=32), "a glowing lamp shade", shade, shadow=False)
    point_light("floor_lamp_bulb", (fx, fy, 1.58), LAMP, 60.0, radius=0.06)
    sx, sy = -2.05, 1.35
    b.add(box("side_table", (0.5, 0.5, 0.55), (sx, sy, 0.275), (0, 0, math.radians(12)), bevel=0.02), "a black wooden side table",
          frame_wood)
    b.add(sphere("table_lamp_base", 0.12, (sx, sy, 0.67)), "a green ceramic lamp base", ceramic)
    b.add(cylinder("table_lamp_shade", 0.17, 0.2, (sx, sy, 0.92), top=0.12, segments=32), "a glowing lamp shade", shade, shadow=False)
    point_light("table_lamp_bulb", (sx, sy, 0.9), LAMP, 35.0, radius=0.05)

    def camera(u: float):
        s = smooth(u)
        return lerp((0.6, -1.75, 1.5), (-1.3, -1.6, 1.45), s), lerp((-2.4, 0.4, 1.25), (1.0, 1.6, 1.1), s)

    return SceneSpec("a living room at night with a tall wall mirror, a window onto a dark blue sky over the city lights, warm"
                     " lamps with glowing shades, a teal velvet sofa and a round black table", camera, fov_y_deg=58.0)
