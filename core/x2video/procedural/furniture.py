"""Furniture categories assembled from primitives, in local coordinates (footprint centred at the origin, front = +z)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

#: (kind, lo, hi, material slot, casts shadow): slots are "main" (the captioned material), "accent", "light"
LocalPart = tuple[str, tuple[float, float, float], tuple[float, float, float], str, bool]


@dataclass
class Design:
    """A piece of furniture in local coordinates: its parts, footprint size and the material families per slot."""

    category: str
    parts: list[LocalPart]
    width: float  # along local x
    depth: float  # along local z
    height: float
    main: tuple[str, ...]  # material families the captioned material is drawn from
    accent: tuple[str, ...] = ("wood",)
    #: for lamps: local position of the bulb (the light source)
    bulb: tuple[float, float, float] | None = None
    blocks_camera: bool = True
    extra: dict = field(default_factory=dict)
    #: caption template for objects whose accent material shows as much as the main one: {main}/{accent} are
    #: "a/an <material>", {main_}/{accent_} the bare material words; None = "a <main material> <category>"
    caption: str | None = None


def _b(x0, y0, z0, x1, y1, z1, slot="main", shadow=True, kind="box") -> LocalPart:
    return (kind, (x0, y0, z0), (x1, y1, z1), slot, shadow)


def _legs(w: float, d: float, h: float, t: float = 0.05, inset: float = 0.03, slot: str = "accent") -> list[LocalPart]:
    xs, zs = (-w / 2 + inset, w / 2 - inset - t), (-d / 2 + inset, d / 2 - inset - t)
    return [_b(x, 0, z, x + t, h, z + t, slot) for x in xs for z in zs]


def sofa(rng: np.random.Generator) -> Design:
    w, d, h = rng.uniform(1.6, 2.4), rng.uniform(0.85, 1.0), rng.uniform(0.75, 0.9)
    leg, seat, arm = 0.1, 0.45, 0.18
    p = _legs(w, d, leg)
    p += [_b(-w / 2, leg, -d / 2, w / 2, seat, d / 2), _b(-w / 2, leg, -d / 2, w / 2, h, -d / 2 + 0.22),
          _b(-w / 2, leg, -d / 2, -w / 2 + arm, 0.62, d / 2), _b(w / 2 - arm, leg, -d / 2, w / 2, 0.62, d / 2)]
    n = 2 if w < 2.0 else 3
    cw = (w - 2 * arm) / n
    for i in range(n):  # seat cushions
        x0 = -w / 2 + arm + i * cw
        p.append(_b(x0 + 0.01, seat, -d / 2 + 0.22, x0 + cw - 0.01, seat + 0.1, d / 2 - 0.02))
    return Design("sofa", p, w, d, h, ("fabric", "fabric", "leather"), ("wood", "metal"))


def armchair(rng: np.random.Generator) -> Design:
    w, d, h = rng.uniform(0.75, 0.95), rng.uniform(0.75, 0.9), rng.uniform(0.75, 0.95)
    p = _legs(w, d, 0.12) + [_b(-w / 2, 0.12, -d / 2, w / 2, 0.45, d / 2), _b(-w / 2, 0.12, -d / 2, w / 2, h, -d / 2 + 0.18),
                               _b(-w / 2, 0.12, -d / 2, -w / 2 + 0.14, 0.62, d / 2), _b(w / 2 - 0.14, 0.12, -d / 2, w / 2, 0.62, d / 2)]
    return Design("armchair", p, w, d, h, ("fabric", "leather"), ("wood", "metal"))


def bed(rng: np.random.Generator) -> Design:
    w, d = rng.choice([1.0, 1.4, 1.6, 1.8]), rng.uniform(2.0, 2.2)
    p = [_b(-w / 2, 0, -d / 2, w / 2, 0.3, d / 2, "accent"), _b(-w / 2, 0, -d / 2, w / 2, rng.uniform(0.9, 1.2), -d / 2 + 0.08, "accent"),
         _b(-w / 2 + 0.03, 0.3, -d / 2 + 0.08, w / 2 - 0.03, 0.55, d / 2 - 0.02),
         _b(-w / 2 + 0.01, 0.5, -d / 2 + 0.6, w / 2 - 0.01, 0.6, d / 2)]  # mattress + duvet (main)
    n = 1 if w < 1.2 else 2
    pw = (w - 0.2) / n
    for i in range(n):
        x0 = -w / 2 + 0.1 + i * pw
        p.append(_b(x0 + 0.03, 0.55, -d / 2 + 0.12, x0 + pw - 0.03, 0.68, -d / 2 + 0.5, "main", kind="sphere"))
    return Design("bed", p, w, d, 1.2, ("fabric",), ("wood", "painted", "leather"), caption="a bed with {main_} bedding on {accent} frame")


def dining_table(rng: np.random.Generator) -> Design:
    w, d, h = rng.uniform(1.2, 2.0), rng.uniform(0.8, 1.0), 0.75
    p = _legs(w, d, h - 0.04, 0.07, 0.06, "main") + [_b(-w / 2, h - 0.04, -d / 2, w / 2, h, d / 2)]
    return Design("dining table", p, w, d, h, ("wood", "wood", "stone", "painted"))


def coffee_table(rng: np.random.Generator) -> Design:
    w, d, h = rng.uniform(0.8, 1.3), rng.uniform(0.5, 0.7), rng.uniform(0.35, 0.45)
    if rng.random() < 0.4:
        p = [_b(-w / 2, 0, -d / 2, w / 2, h, d / 2, kind="cylinder")] if rng.random() < 0.5 else [
            _b(-w / 2, h - 0.04, -d / 2, w / 2, h, d / 2), _b(-0.08, 0, -0.08, 0.08, h - 0.04, 0.08, "main", kind="cylinder")]
    else:
        p = _legs(w, d, h - 0.04, 0.05, 0.03, "main") + [_b(-w / 2, h - 0.04, -d / 2, w / 2, h, d / 2)]
    return Design("coffee table", p, w, d, h, ("wood", "stone", "metal", "painted"))


def chair(rng: np.random.Generator) -> Design:
    w, d = rng.uniform(0.42, 0.5), rng.uniform(0.45, 0.52)
    p = _legs(w, d, 0.44, 0.04, 0.01, "main") + [_b(-w / 2, 0.44, -d / 2, w / 2, 0.48, d / 2),
                                                 _b(-w / 2, 0.48, -d / 2, w / 2, rng.uniform(0.85, 0.95), -d / 2 + 0.04)]
    return Design("chair", p, w, d, 0.9, ("wood", "plastic", "painted", "metal"))


def desk(rng: np.random.Generator) -> Design:
    w, d, h = rng.uniform(1.1, 1.6), rng.uniform(0.6, 0.75), 0.75
    p = [_b(-w / 2, h - 0.04, -d / 2, w / 2, h, d / 2), _b(-w / 2, 0, -d / 2, -w / 2 + 0.04, h - 0.04, d / 2),
         _b(w / 2 - 0.04, 0, -d / 2, w / 2, h - 0.04, d / 2), _b(-w / 2, 0.3, -d / 2, w / 2, h - 0.04, -d / 2 + 0.03)]
    return Design("desk", p, w, d, h, ("wood", "painted", "plastic"))


def wardrobe(rng: np.random.Generator) -> Design:
    w, d, h = rng.uniform(1.0, 2.0), rng.uniform(0.55, 0.65), rng.uniform(1.9, 2.2)
    n = int(round(w / 0.5))
    p = [_b(-w / 2, 0, -d / 2, w / 2, h, d / 2 - 0.02)]
    dw = w / n
    for i in range(n):  # door panels with a gap between them, and a metal handle each
        x0 = -w / 2 + i * dw
        p.append(_b(x0 + 0.005, 0.05, d / 2 - 0.02, x0 + dw - 0.005, h - 0.03, d / 2))
        hx = x0 + (dw - 0.06 if i % 2 == 0 else 0.04)
        p.append(_b(hx, h / 2 - 0.15, d / 2, hx + 0.02, h / 2 + 0.15, d / 2 + 0.03, "accent"))
    return Design("wardrobe", p, w, d, h, ("wood", "painted"), ("metal",))


def bookshelf(rng: np.random.Generator) -> Design:
    w, d, h = rng.uniform(0.8, 1.4), rng.uniform(0.3, 0.4), rng.uniform(1.6, 2.1)
    t = 0.025
    p = [_b(-w / 2, 0, -d / 2, -w / 2 + t, h, d / 2), _b(w / 2 - t, 0, -d / 2, w / 2, h, d / 2), _b(-w / 2, 0, -d / 2, w / 2, h, -d / 2 + t)]
    n = int(h / 0.38)
    for i in range(n + 1):
        y = min(i * h / n, h - t)
        p.append(_b(-w / 2, y, -d / 2, w / 2, y + t, d / 2))
    return Design("bookshelf", p, w, d, h, ("wood", "painted", "metal"))


def cabinet(rng: np.random.Generator) -> Design:
    w, d, h = rng.uniform(0.8, 1.6), rng.uniform(0.4, 0.5), rng.uniform(0.6, 0.95)
    p = [_b(-w / 2, 0.08, -d / 2, w / 2, h, d / 2 - 0.02)] + _legs(w, d, 0.08, 0.04, 0.03, "main")
    n = 3 if h > 0.8 else 2
    for i in range(n):  # drawer fronts with handles
        y0 = 0.08 + i * (h - 0.08) / n
        y1 = y0 + (h - 0.08) / n
        p.append(_b(-w / 2 + 0.01, y0 + 0.01, d / 2 - 0.02, w / 2 - 0.01, y1 - 0.01, d / 2))
        p.append(_b(-0.1, (y0 + y1) / 2 - 0.01, d / 2, 0.1, (y0 + y1) / 2 + 0.01, d / 2 + 0.025, "accent"))
    return Design("cabinet", p, w, d, h, ("wood", "painted", "plastic", "stone"), ("metal",))


def nightstand(rng: np.random.Generator) -> Design:
    w, d, h = rng.uniform(0.4, 0.55), rng.uniform(0.35, 0.45), rng.uniform(0.45, 0.6)
    p = [_b(-w / 2, 0, -d / 2, w / 2, h, d / 2 - 0.02), _b(-w / 2 + 0.02, h / 2, d / 2 - 0.02, w / 2 - 0.02, h - 0.02, d / 2),
         _b(-0.06, 0.75 * h - 0.01, d / 2, 0.06, 0.75 * h + 0.01, d / 2 + 0.02, "accent")]
    return Design("nightstand", p, w, d, h, ("wood", "painted"), ("metal",))


def floor_lamp(rng: np.random.Generator) -> Design:
    h, r = rng.uniform(1.4, 1.7), rng.uniform(0.18, 0.25)
    p = [_b(-0.15, 0, -0.15, 0.15, 0.03, 0.15, "accent", kind="cylinder"), _b(-0.015, 0.03, -0.015, 0.015, h - 0.3, 0.015, "accent", kind="cylinder"),
         _b(-r, h - 0.35, -r, r, h, r, "main", False, kind="cylinder")]
    return Design("floor lamp", p, 2 * r, 2 * r, h, ("fabric",), ("metal",), bulb=(0.0, h - 0.2, 0.0),
                  caption="a floor lamp with {main} shade on {accent} stand")


def table_lamp(rng: np.random.Generator) -> Design:
    r = rng.uniform(0.1, 0.14)
    p = [_b(-0.05, 0, -0.05, 0.05, 0.2, 0.05, "accent", kind="cylinder"), _b(-r, 0.2, -r, r, 0.42, r, "main", False, kind="cylinder")]
    return Design("table lamp", p, 2 * r, 2 * r, 0.42, ("fabric",), ("ceramic", "metal"), bulb=(0.0, 0.3, 0.0), blocks_camera=False,
                  caption="a table lamp with {main} shade on {accent} base")


def plant(rng: np.random.Generator) -> Design:
    r, ph = rng.uniform(0.12, 0.2), rng.uniform(0.25, 0.4)
    fh = rng.uniform(0.6, 1.3)
    p = [_b(-r, 0, -r, r, ph, r, "accent", kind="cylinder")]
    fr = r * rng.uniform(1.6, 2.2)
    for i in range(4):  # foliage: a few overlapping ellipsoids
        a = i * np.pi / 2 + rng.uniform(0, 0.8)
        cx, cz = 0.35 * fr * np.cos(a), 0.35 * fr * np.sin(a)
        y0 = ph + (i / 4) * fh * 0.4
        p.append(_b(cx - fr * 0.7, y0, cz - fr * 0.7, cx + fr * 0.7, y0 + fh * 0.6, cz + fr * 0.7, kind="sphere"))
    return Design("potted plant", p, 2 * fr * 1.05, 2 * fr * 1.05, ph + fh, ("foliage",), ("ceramic", "plastic", "concrete"),
                  caption="a potted plant with {main_} foliage in {accent} pot")


def rug(rng: np.random.Generator) -> Design:
    w, d = rng.uniform(1.4, 3.0), rng.uniform(1.2, 2.2)
    return Design("rug", [_b(-w / 2, 0, -d / 2, w / 2, 0.012, d / 2, shadow=False)], w, d, 0.012, ("fabric",), blocks_camera=False)


def tv(rng: np.random.Generator) -> Design:
    w = rng.uniform(0.9, 1.4)
    h = w * 0.58
    p = [_b(-w / 2, 0, -0.03, w / 2, h, 0.03)]
    return Design("television", p, w, 0.06, h, ("plastic",), blocks_camera=False, extra={"colours": ("black",)})


def painting(rng: np.random.Generator) -> Design:
    w, h = rng.uniform(0.5, 1.2), rng.uniform(0.4, 0.9)
    p = [_b(-w / 2, 0, -0.02, w / 2, h, 0.0, "accent"), _b(-w / 2 + 0.04, 0.04, -0.02, w / 2 - 0.04, h - 0.04, 0.01)]
    return Design("painting", p, w, 0.03, h, ("canvas",), ("wood", "metal"), blocks_camera=False,
                  caption="{main} painting in {accent} frame")


def vase(rng: np.random.Generator) -> Design:
    r, h = rng.uniform(0.06, 0.12), rng.uniform(0.2, 0.45)
    p = [_b(-r, 0, -r, r, h * 0.75, r, kind="cylinder"), _b(-r * 0.55, h * 0.75, -r * 0.55, r * 0.55, h, r * 0.55, kind="cylinder")]
    return Design("vase", p, 2 * r, 2 * r, h, ("ceramic", "ceramic", "stone", "metal"), blocks_camera=False)


#: every category the room builder can place
CATEGORIES: dict[str, Callable[[np.random.Generator], Design]] = {
    "sofa": sofa, "armchair": armchair, "bed": bed, "dining table": dining_table, "coffee table": coffee_table,
    "chair": chair, "desk": desk, "wardrobe": wardrobe, "bookshelf": bookshelf, "cabinet": cabinet,
    "nightstand": nightstand, "floor lamp": floor_lamp, "table lamp": table_lamp, "potted plant": plant,
    "rug": rug, "television": tv, "painting": painting, "vase": vase,
}
