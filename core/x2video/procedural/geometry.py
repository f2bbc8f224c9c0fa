"""Primitive parts (axis-aligned boxes, vertical cylinders, ellipsoids) and their triangle meshes for procedural rooms."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: the three primitive kinds; every one fills the axis-aligned box [lo, hi]
KINDS = ("box", "cylinder", "sphere")


@dataclass
class Part:
    """One primitive filling the world-space box [lo, hi] (metres, y up), with a material index."""

    kind: str
    lo: np.ndarray  # (3,)
    hi: np.ndarray  # (3,)
    material: int
    #: parts that light passes through (lamp shades around their own bulb, window glass) cast no shadow
    casts_shadow: bool = True

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown part kind {self.kind!r}")
        self.lo = np.minimum(np.asarray(self.lo, np.float64), np.asarray(self.hi, np.float64))
        self.hi = np.maximum(np.asarray(self.lo, np.float64), np.asarray(self.hi, np.float64))


@dataclass
class SceneObject:
    """A captioned object: its id in the ids channel, category, caption and parts."""

    id: int
    category: str
    caption: str
    parts: list[Part] = field(default_factory=list)
    #: whether the camera path must keep clear of its floor footprint
    blocks_camera: bool = True

    @property
    def lo(self) -> np.ndarray:
        return np.min([p.lo for p in self.parts], axis=0)

    @property
    def hi(self) -> np.ndarray:
        return np.max([p.hi for p in self.parts], axis=0)


def rotate_y(lo: np.ndarray, hi: np.ndarray, quarter_turns: int, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotate the box [lo, hi] (local coordinates, front = +z) by quarter turns about +y, then translate by origin."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    k = quarter_turns % 4
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][k]
    # rotation about +y by k*90 degrees: x' = c x + s z, z' = -s x + c z
    rx = c * corners[:, 0] + s * corners[:, 2]
    rz = -s * corners[:, 0] + c * corners[:, 2]
    pts = np.stack([rx, corners[:, 1], rz], 1) + origin
    return pts.min(0), pts.max(0)


# ---------------------------------------------------------------------------------------------- meshes
_BOX_FACES = (  # (normal, 4 corners as (x,y,z) picks of lo(0)/hi(1)) counter-clockwise seen from outside
    ((1, 0, 0), ((1, 0, 1), (1, 0, 0), (1, 1, 0), (1, 1, 1))),
    ((-1, 0, 0), ((0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0))),
    ((0, 1, 0), ((0, 1, 1), (1, 1, 1), (1, 1, 0), (0, 1, 0))),
    ((0, -1, 0), ((0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1))),
    ((0, 0, 1), ((0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1))),
    ((0, 0, -1), ((1, 0, 0), (0, 0, 0), (0, 1, 0), (1, 1, 0))),
)


def _box(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pos, nrm = [], []
    lh = np.stack([lo, hi])  # (2, 3)
    for n, quad in _BOX_FACES:
        c = [np.array([lh[q[0], 0], lh[q[1], 1], lh[q[2], 2]]) for q in quad]
        for i in (0, 1, 2, 0, 2, 3):
            pos.append(c[i])
            nrm.append(n)
    return np.array(pos), np.array(nrm, np.float64)


def _cylinder(lo: np.ndarray, hi: np.ndarray, seg: int = 20) -> tuple[np.ndarray, np.ndarray]:
    cx, cz = (lo[0] + hi[0]) / 2, (lo[2] + hi[2]) / 2
    rx, rz = (hi[0] - lo[0]) / 2, (hi[2] - lo[2]) / 2
    a = np.linspace(0, 2 * np.pi, seg + 1)
    ring = np.stack([cx + rx * np.cos(a), cz - rz * np.sin(a)], 1)  # counter-clockwise seen from +y
    nr = np.stack([np.cos(a) / max(rx, 1e-6), -np.sin(a) / max(rz, 1e-6)], 1)
    nr /= np.linalg.norm(nr, axis=1, keepdims=True)
    pos, nrm = [], []
    y0, y1 = lo[1], hi[1]
    for i in range(seg):
        p00, p10 = (ring[i, 0], y0, ring[i, 1]), (ring[i + 1, 0], y0, ring[i + 1, 1])
        p01, p11 = (ring[i, 0], y1, ring[i, 1]), (ring[i + 1, 0], y1, ring[i + 1, 1])
        n0, n1 = (nr[i, 0], 0, nr[i, 1]), (nr[i + 1, 0], 0, nr[i + 1, 1])
        pos += [p00, p10, p11, p00, p11, p01]
        nrm += [n0, n1, n1, n0, n1, n0]
        pos += [(cx, y1, cz), p01, p11]
        nrm += [(0, 1, 0)] * 3
        pos += [(cx, y0, cz), p10, p00]
        nrm += [(0, -1, 0)] * 3
    return np.array(pos, np.float64), np.array(nrm, np.float64)


def _sphere(lo: np.ndarray, hi: np.ndarray, seg: int = 16, rings: int = 10) -> tuple[np.ndarray, np.ndarray]:
    c, r = (lo + hi) / 2, (hi - lo) / 2
    th, ph = np.meshgrid(np.linspace(0, np.pi, rings + 1), np.linspace(0, 2 * np.pi, seg + 1), indexing="ij")
    unit = np.stack([np.sin(th) * np.cos(ph), np.cos(th), -np.sin(th) * np.sin(ph)], -1)  # (rings+1, seg+1, 3)
    q = [unit[:-1, :-1], unit[1:, :-1], unit[1:, 1:], unit[:-1, 1:]]  # quad corners, each (rings, seg, 3)
    u = np.stack([q[k] for k in (0, 1, 2, 0, 2, 3)], 2).reshape(-1, 3)  # (rings*seg*6, 3)
    n = u / np.maximum(r, 1e-6)
    return c + r * u, n / np.linalg.norm(n, axis=1, keepdims=True)


def part_mesh(part: Part) -> tuple[np.ndarray, np.ndarray]:
    """Triangle soup of one part: positions (V, 3) and unit normals (V, 3), V a multiple of 3, counter-clockwise outside."""
    fn = {"box": _box, "cylinder": _cylinder, "sphere": _sphere}[part.kind]
    return fn(part.lo, part.hi)


def scene_vertices(objects: list[SceneObject]) -> np.ndarray:
    """All objects as one interleaved float32 array (V, 9): position 3, normal 3, material, object id, casts-shadow."""
    chunks = []
    for obj in objects:
        for part in obj.parts:
            pos, nrm = part_mesh(part)
            extra = np.tile([part.material, obj.id, 1.0 if part.casts_shadow else 0.0], (len(pos), 1))
            chunks.append(np.concatenate([pos, nrm, extra], 1))
    return np.concatenate(chunks, 0).astype(np.float32)
