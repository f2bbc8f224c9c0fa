"""The room shell: floor, ceiling and walls (boxes around door and window openings), window frames, sky panes and a door."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from x2video.procedural.geometry import Part

WALL_T = 0.15  #: wall thickness, metres


@dataclass
class Opening:
    """A hole in wall `wall` (0: z=0, 1: x=W, 2: z=D, 3: x=0) spanning u in [u0, u1] along the wall and y in [y0, y1]."""

    wall: int
    u0: float
    u1: float
    y0: float
    y1: float
    kind: str  # "window" | "door"


def wall_frame(wall: int, w: float, d: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(origin, u axis, inward normal, length) of a wall: point(u, y) = origin + u * axis + y * up."""
    if wall == 0:
        return np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 0, 1]), w
    if wall == 1:
        return np.array([w, 0, 0.0]), np.array([0.0, 0, 1]), np.array([-1.0, 0, 0]), d
    if wall == 2:
        return np.array([0.0, 0, d]), np.array([1.0, 0, 0]), np.array([0.0, 0, -1]), w
    if wall == 3:
        return np.array([0.0, 0, 0]), np.array([0.0, 0, 1]), np.array([1.0, 0, 0]), d
    raise ValueError(f"wall index {wall} not in 0..3")


def wall_box(wall: int, w: float, d: float, u0: float, u1: float, y0: float, y1: float, n0: float, n1: float) -> tuple[np.ndarray, np.ndarray]:
    """World box spanning [u0,u1] along the wall, [y0,y1] up and [n0,n1] along the inward normal."""
    o, a, n, _ = wall_frame(wall, w, d)
    pts = [o + u * a + y * np.array([0, 1.0, 0]) + t * n for u in (u0, u1) for y in (y0, y1) for t in (n0, n1)]
    pts = np.array(pts)
    return pts.min(0), pts.max(0)


def wall_parts(wall: int, w: float, d: float, h: float, openings: list[Opening], material: int) -> list[Part]:
    """Boxes covering wall `wall` (outside the room, thickness WALL_T) except its openings; corners closed."""
    _, _, _, length = wall_frame(wall, w, d)
    ops = sorted([o for o in openings if o.wall == wall], key=lambda o: o.u0)
    lo_u, hi_u = (-WALL_T, length + WALL_T) if wall in (0, 2) else (0.0, length)
    cuts = sorted({lo_u, hi_u, *[o.u0 for o in ops], *[o.u1 for o in ops]})
    parts = []
    for u0, u1 in zip(cuts[:-1], cuts[1:]):
        mid = (u0 + u1) / 2
        holes = sorted([(o.y0, o.y1) for o in ops if o.u0 <= mid <= o.u1])
        y = 0.0
        for y0, y1 in holes + [(h, h)]:
            if y0 > y + 1e-6:
                lo, hi = wall_box(wall, w, d, u0, u1, y, y0, -WALL_T, 0.0)
                parts.append(Part("box", lo, hi, material))
            y = max(y, y1)
    return parts


def window_frame_parts(op: Opening, w: float, d: float, material: int) -> list[Part]:
    """A frame (border and a cross of mullions) in the middle of the wall thickness."""
    t, n0, n1 = 0.05, -WALL_T * 0.6, -WALL_T * 0.4
    u0, u1, y0, y1 = op.u0, op.u1, op.y0, op.y1
    um, ym = (u0 + u1) / 2, y0 + 0.6 * (y1 - y0)
    spans = [(u0, u0 + t, y0, y1), (u1 - t, u1, y0, y1), (u0, u1, y0, y0 + t), (u0, u1, y1 - t, y1),
             (um - t / 2, um + t / 2, y0, y1), (u0, u1, ym - t / 2, ym + t / 2)]
    return [Part("box", *wall_box(op.wall, w, d, a, b, c, e, n0, n1), material) for a, b, c, e in spans]


def sky_part(op: Opening, w: float, d: float, material: int) -> Part:
    """The pane showing the sky, at the outer face of the wall; it casts no shadow so sunlight passes."""
    lo, hi = wall_box(op.wall, w, d, op.u0, op.u1, op.y0, op.y1, -WALL_T - 0.01, -WALL_T)
    return Part("box", lo, hi, material, casts_shadow=False)


def door_parts(op: Opening, w: float, d: float, material: int, handle: int) -> list[Part]:
    """A closed door leaf set into the opening, with a metal handle on the room side."""
    lo, hi = wall_box(op.wall, w, d, op.u0, op.u1, op.y0, op.y1, -0.09, -0.05)
    hlo, hhi = wall_box(op.wall, w, d, op.u1 - 0.15, op.u1 - 0.05, 1.0, 1.03, -0.05, 0.0)
    return [Part("box", lo, hi, material), Part("box", hlo, hhi, handle)]


def window_centre(op: Opening, w: float, d: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(centre on the room side, inward normal, area) of a window opening."""
    o, a, n, _ = wall_frame(op.wall, w, d)
    c = o + a * (op.u0 + op.u1) / 2 + np.array([0, 1.0, 0]) * (op.y0 + op.y1) / 2
    return c, n, (op.u1 - op.u0) * (op.y1 - op.y0)
