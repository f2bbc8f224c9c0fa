"""A kitchen: sage cabinets with rounded edges, a marble countertop, a tiled backsplash, a steel fridge,
oven and tapered hood, a walnut island turned a little off the walls, stools, glowing pendant globes.
The camera dollies along the island while panning from the sink side to the fridge."""
from __future__ import annotations

import math

from x2video.cycles.outside.build import Builder, SceneSpec, area_light, box, cylinder, lerp, plane, point_light, smooth, sphere, world

W, D, H = 4.8, 4.0, 2.7  # room: x in [-W/2, W/2], y in [-D/2, D/2], z in [0, H]
WARM = (1.0, 0.74, 0.45)


def build(b: Builder) -> SceneSpec:
    # --- materials
    plaster = b.material("plaster", (0.78, 0.75, 0.69), 0.85)
    ceiling = b.material("ceiling", (0.82, 0.82, 0.8), 0.9)
    oak = b.textured(b.material("oak_floor", (0.45, 0.3, 0.17), 0.4), "brick", (0.42, 0.27, 0.15), (0.5, 0.34, 0.2),
                     scale=1.0, mortar=(0.2, 0.13, 0.07), brick=(1.2, 0.16), mortar_size=0.004)
    sage = b.material("sage_paint", (0.2, 0.29, 0.23), 0.45)
    marble = b.textured(b.material("marble", (0.75, 0.75, 0.73), 0.15), "noise", (0.82, 0.82, 0.8), (0.5, 0.5, 0.52), scale=3.0)
    tiles = b.textured(b.material("tiles", (0.7, 0.78, 0.8), 0.12), "brick", (0.62, 0.74, 0.78), (0.7, 0.8, 0.82),
                       scale=1.0, mortar=(0.85, 0.85, 0.82), brick=(0.15, 0.075), mortar_size=0.004)
    steel = b.material("brushed_steel", (0.58, 0.58, 0.6), 0.3, metallic=1.0)
    steel_hood = b.material("steel_hood", (0.6, 0.6, 0.62), 0.2, metallic=1.0)
    steel_dark = b.material("dark_steel", (0.2, 0.2, 0.21), 0.35, metallic=1.0)
    black_glass = b.material("black_glass", (0.02, 0.02, 0.02), 0.05)
    walnut = b.textured(b.material("walnut", (0.2, 0.1, 0.05), 0.4), "wave", (0.25, 0.13, 0.06), (0.12, 0.06, 0.03), scale=4.0)
    ceramic = b.material("ceramic", (0.85, 0.84, 0.8), 0.1)
    orange = b.material("orange", (0.8, 0.3, 0.03), 0.5)
    globe = b.material("globe", (0.9, 0.85, 0.8), 0.5, emission=WARM, strength=6.0)

    # --- the room
    b.add(box("floor", (W, D, 0.1), (0, 0, -0.05)), "a light oak plank floor", oak)
    b.add(box("ceiling", (W, D, 0.1), (0, 0, H + 0.05)), "a white ceiling", ceiling)
    b.add(box("wall_back", (W, 0.1, H), (0, D / 2 + 0.05, H / 2)), "a plastered wall", plaster)
    b.add(box("wall_front", (W, 0.1, H), (0, -D / 2 - 0.05, H / 2)), "a plastered wall", plaster)
    b.add(box("wall_left", (0.1, D, H), (-W / 2 - 0.05, 0, H / 2)), "a plastered wall", plaster)
    b.add(box("wall_right", (0.1, D, H), (W / 2 + 0.05, 0, H / 2)), "a plastered wall", plaster)

    # --- the counter run along the back wall: cabinets, oven, countertop, backsplash, upper cabinets
    yb = D / 2 - 0.31
    for i, (x0, x1) in enumerate(((-2.3, -1.7), (-1.7, -1.1), (-1.1, -0.5), (0.1, 0.7), (0.7, 1.3))):
        xc = (x0 + x1) / 2
        b.add(box(f"cabinet_{i}", (x1 - x0 - 0.012, 0.6, 0.8), (xc, yb, 0.5), bevel=0.012), "a sage green kitchen cabinet", sage)
        b.add(cylinder(f"cab_handle_{i}", 0.008, 0.22, (xc, yb - 0.33, 0.8), (0, math.pi / 2, 0), segments=12),
              "a steel cabinet handle", steel)
    b.add(box("plinth", (3.6, 0.55, 0.1), (-0.5, yb + 0.02, 0.05)), "a dark plinth", steel_dark)
    b.add(box("oven", (0.58, 0.6, 0.8), (-0.2, yb, 0.5), bevel=0.01), "a brushed steel oven", steel)
    b.add(box("oven_window", (0.44, 0.01, 0.28), (-0.2, yb - 0.305, 0.48), bevel=0.004), "the oven's black glass door", black_glass)
    b.add(cylinder("oven_handle", 0.01, 0.46, (-0.2, yb - 0.35, 0.72), (0, math.pi / 2, 0), segments=12), "a steel oven handle", steel)
    b.add(box("countertop", (3.64, 0.66, 0.04), (-0.49, yb - 0.02, 0.92), bevel=0.01), "a white marble countertop", marble)
    b.add(box("cooktop", (0.56, 0.48, 0.008), (-0.2, yb, 0.944), bevel=0.003), "a black glass cooktop", black_glass)
    b.add(plane("backsplash", (3.64, 0.52), (-0.49, D / 2 - 0.002, 1.2), (math.pi / 2, 0, 0)), "a pale blue tiled backsplash", tiles)
    for i, (x0, x1) in enumerate(((-2.3, -1.45), (-1.45, -0.6), (0.2, 0.76), (0.76, 1.32))):
        b.add(box(f"upper_{i}", (x1 - x0 - 0.012, 0.34, 0.7), ((x0 + x1) / 2, D / 2 - 0.17, 1.85), bevel=0.012),
              "a sage green wall cabinet", sage)
    # a hood: a square frustum turned 45 degrees, under a chimney
    b.add(cylinder("hood", 0.46, 0.32, (-0.2, D / 2 - 0.33, 1.72), (0, 0, math.pi / 4), top=0.16, segments=4),
          "a brushed steel cooker hood", steel_hood)
    b.add(box("chimney", (0.24, 0.24, 0.82), (-0.2, D / 2 - 0.33, 2.29), bevel=0.005), "the hood's steel chimney", steel_hood)
    # a fridge with two doors and tall handles
    b.add(box("fridge", (0.88, 0.7, 1.95), (1.86, D / 2 - 0.36, 0.985), bevel=0.03), "a brushed steel fridge", steel)
    b.add(box("fridge_seam", (0.86, 0.004, 0.006), (1.86, D / 2 - 0.713, 1.2)), "the fridge door seam", steel_dark)
    for i, (z, length) in enumerate(((1.55, 0.55), (0.75, 0.7))):
        b.add(cylinder(f"fridge_handle_{i}", 0.012, length, (1.5, D / 2 - 0.76, z), segments=12), "a steel fridge handle", steel)

    # --- a walnut island turned 8 degrees, with a marble top, a fruit bowl and two stools
    rot = (0, 0, math.radians(8))
    b.add(box("island", (1.6, 0.8, 0.88), (0.1, -0.1, 0.44), rot, bevel=0.03), "a walnut kitchen island", walnut)
    b.add(box("island_top", (1.72, 0.92, 0.04), (0.1, -0.1, 0.9), rot, bevel=0.012), "a white marble island top", marble)
    b.add(sphere("bowl", 0.16, (0.3, -0.05, 0.97), (1, 1, 0.45)), "a white ceramic bowl", ceramic)
    for i, (dx, dy) in enumerate(((0.0, 0.0), (0.06, 0.05), (-0.05, 0.05))):
        b.add(sphere(f"orange_{i}", 0.04, (0.3 + dx, -0.05 + dy, 1.02)), "an orange", orange)
    for i, x in enumerate((-0.35, 0.45)):
        y = -0.1 - 0.62 + 0.14 * (x - 0.1)  # follow the island's turn
        b.add(cylinder(f"stool_seat_{i}", 0.18, 0.05, (x, y, 0.72)), "a dark steel bar stool", steel_dark)
        b.add(cylinder(f"stool_leg_{i}", 0.025, 0.7, (x, y, 0.35), segments=16), "a dark steel stool leg", steel_dark)
        b.add(cylinder(f"stool_foot_{i}", 0.16, 0.02, (x, y, 0.01)), "a dark steel stool foot", steel_dark)

    # --- lights: two warm pendant globes over the island, a cool ceiling panel, a warm strip under the wall cabinets
    for i, x in enumerate((-0.35, 0.55)):
        y = -0.1 + 0.14 * (x - 0.1)
        b.add(sphere(f"pendant_{i}", 0.1, (x, y, 1.85)), "a glowing glass pendant globe", globe, shadow=False)
        b.add(cylinder(f"cord_{i}", 0.004, H - 1.95, (x, y, (H + 1.95) / 2), segments=8), "a pendant cord", steel_dark)
        point_light(f"pendant_light_{i}", (x, y, 1.85), WARM, 40.0, radius=0.08)
    area_light("ceiling_panel", (1.2, 0.6), (0.0, 0.5, H - 0.02), (0.88, 0.93, 1.0), 180.0)
    area_light("under_cabinet", (2.5, 0.05), (-0.9, D / 2 - 0.3, 1.48), (1.0, 0.82, 0.6), 25.0)
    world((0.05, 0.05, 0.06), 0.2)

    def camera(u: float):
        s = smooth(u)
        return lerp((-1.9, -1.75, 1.65), (1.0, -1.55, 1.55), s), lerp((-0.7, 1.6, 1.0), (1.1, 1.4, 1.0), s)

    return SceneSpec("a modern kitchen with sage green cabinets, a marble countertop, a tiled backsplash, a steel fridge, oven and"
                     " hood, and a walnut island under two glowing pendants", camera, fov_y_deg=60.0)
