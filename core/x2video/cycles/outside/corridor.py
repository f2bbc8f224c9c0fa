"""A long corridor: a polished stone floor (roughness 0.05) mirroring warm ceiling panels, panelled doors
in white frames with brass levers on both sides, a painting in a gilt frame, a potted plant at the far
end. The camera walks down the corridor, swaying a little."""
from __future__ import annotations

import math

from x2video.cycles.outside.build import Builder, SceneSpec, area_light, box, cylinder, plane, smooth, sphere, world

W, L, H = 2.2, 15.0, 2.8  # x in [-W/2, W/2], y in [-1, L - 1], z in [0, H]
Y0 = -1.0
PANEL = (1.0, 0.9, 0.76)


def door(b: Builder, i: int, side: int, y: float, wood, frame, brass) -> None:
    """A door in the wall at x = side * W/2: a bevelled wooden leaf in a white frame, a brass lever."""
    x = side * (W / 2 - 0.02)
    b.add(box(f"door_{i}", (0.04, 0.9, 2.05), (x, y, 1.025), bevel=0.008), "a panelled oak door", wood)
    for j, (dy, dz, sy, sz) in enumerate(((-0.5, 1.06, 0.08, 2.12), (0.5, 1.06, 0.08, 2.12), (0.0, 2.1, 1.08, 0.08))):
        b.add(box(f"door_{i}_frame_{j}", (0.06, sy, sz), (side * (W / 2 - 0.03), y + dy, dz), bevel=0.01), "a white door frame", frame)
    for j, dz in enumerate((0.55, 1.45)):  # two raised panels on the leaf
        b.add(box(f"door_{i}_panel_{j}", (0.02, 0.6, 0.7), (x - side * 0.025, y, dz), bevel=0.015), "a raised door panel", wood)
    hy = y + 0.35 * (1 if (i % 2) else -1)
    b.add(cylinder(f"door_{i}_rose", 0.03, 0.02, (x - side * 0.03, hy, 1.0), (0, math.pi / 2, 0)), "a brass door rose", brass)
    b.add(cylinder(f"door_{i}_lever", 0.011, 0.13, (x - side * 0.06, hy - 0.05 * (1 if (i % 2) else -1), 1.0), (math.pi / 2, 0, 0),
                   segments=12), "a brass door lever", brass)


def build(b: Builder) -> SceneSpec:
    stone = b.textured(b.material("polished_stone", (0.46, 0.42, 0.37), 0.05), "brick", (0.44, 0.4, 0.35), (0.52, 0.48, 0.42),
                       scale=1.0, mortar=(0.25, 0.23, 0.2), brick=(0.6, 0.6), mortar_size=0.006)
    wall = b.material("green_grey_paint", (0.5, 0.57, 0.52), 0.75)
    ceiling = b.material("ceiling", (0.8, 0.8, 0.78), 0.9)
    skirting = b.material("white_gloss_paint", (0.8, 0.8, 0.78), 0.2)
    wood = b.textured(b.material("oak", (0.45, 0.3, 0.17), 0.45), "wave", (0.5, 0.33, 0.19), (0.36, 0.22, 0.11), scale=3.0)
    frame = b.material("white_paint", (0.78, 0.78, 0.76), 0.5)
    brass = b.material("brass", (0.91, 0.76, 0.42), 0.25, metallic=1.0)
    gilt = b.material("gilt", (0.85, 0.65, 0.32), 0.3, metallic=1.0)
    canvas = b.textured(b.material("canvas", (0.4, 0.25, 0.3), 0.6), "noise", (0.75, 0.35, 0.1), (0.1, 0.25, 0.5), scale=2.5)
    panel = b.material("light_panel", (0.9, 0.9, 0.9), 0.5, emission=PANEL, strength=8.0)
    terracotta = b.material("terracotta", (0.55, 0.22, 0.1), 0.7)
    leaves = b.material("leaves", (0.05, 0.2, 0.04), 0.6)

    yc = Y0 + L / 2
    b.add(box("floor", (W, L, 0.1), (0, yc, -0.05)), "a polished stone tile floor", stone)
    b.add(box("ceiling", (W, L, 0.1), (0, yc, H + 0.05)), "a white ceiling", ceiling)
    b.add(box("wall_left", (0.1, L, H), (-W / 2 - 0.05, yc, H / 2)), "a green-grey corridor wall", wall)
    b.add(box("wall_right", (0.1, L, H), (W / 2 + 0.05, yc, H / 2)), "a green-grey corridor wall", wall)
    b.add(box("wall_end", (W, 0.1, H), (0, Y0 + L + 0.05, H / 2)), "a green-grey end wall", wall)
    b.add(box("wall_start", (W, 0.1, H), (0, Y0 - 0.05, H / 2)), "a green-grey wall", wall)
    for s, name in ((-1, "left"), (1, "right")):
        b.add(box(f"skirting_{name}", (0.02, L, 0.12), (s * (W / 2 - 0.01), yc, 0.06), bevel=0.004), "a white skirting board", skirting)

    for i, (side, y) in enumerate(((-1, 2.0), (1, 3.6), (-1, 5.6), (1, 7.4), (-1, 9.2), (1, 11.0))):
        door(b, i, side, y, wood, frame, brass)
    # a painting between the first two doors on the left, a plant at the end
    b.add(box("painting_frame", (0.04, 1.0, 0.75), (-W / 2 + 0.02, 3.8, 1.55), bevel=0.012), "a gilt picture frame", gilt)
    b.add(plane("painting", (0.86, 0.61), (-W / 2 + 0.045, 3.8, 1.55), (0, math.pi / 2, 0)), "an abstract painting", canvas)
    b.add(cylinder("pot", 0.2, 0.45, (0.55, L + Y0 - 0.35, 0.225), top=0.26), "a terracotta pot", terracotta)
    b.add(sphere("plant", 0.38, (0.55, L + Y0 - 0.35, 0.8), (1, 1, 1.3)), "a leafy plant", leaves)

    # ceiling panels (seen) with area lights just below them (lighting), warm white
    for i, y in enumerate((0.5, 3.4, 6.3, 9.2, 12.1)):
        b.add(plane(f"panel_{i}", (0.5, 1.1), (0, y, H - 0.005), (math.pi, 0, 0)), "a glowing ceiling panel", panel, shadow=False)
        area_light(f"panel_light_{i}", (0.5, 1.1), (0, y, H - 0.02), PANEL, 70.0)
    world((0.05, 0.05, 0.06), 0.2)

    def camera(u: float):
        s = smooth(u)
        y = -0.5 + 4.5 * s
        sway = 0.12 * math.sin(2 * math.pi * s)
        return (sway - 0.1, y, 1.6 + 0.02 * math.sin(4 * math.pi * s)), (0.25 * math.sin(math.pi * s) - 0.05, y + 6.0, 1.35)

    return SceneSpec("a long corridor with a polished stone floor, oak doors in white frames, brass levers, a painting and"
                     " warm ceiling lights", camera, fov_y_deg=60.0)
