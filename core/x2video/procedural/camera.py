"""Camera paths as the paper's data set section describes: eye height 1.7 m, start at a corner or wall midpoint facing the
room centre, 900 collision-free candidates per step drawn with weight (visible objects)^2, smooth B-spline at ~0.05 m/frame."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from x2video.procedural.scene import Scene
from x2video.shot import CameraPose


@dataclass
class PathConfig:
    """How camera paths are drawn."""

    eye_height: float = 1.7
    #: metres travelled per frame (paper: ~0.05)
    speed: float = 0.05
    #: candidate positions per step (paper: 900)
    candidates: int = 900
    #: distance between consecutive waypoints, metres
    step: float = 0.5
    #: largest change of heading between waypoints, degrees
    max_turn: float = 3.0
    #: largest change of walking direction between waypoints, degrees
    max_bend: float = 45.0
    #: camera pitch range, degrees (negative = looking down)
    pitch: tuple[float, float] = (-16.0, -6.0)
    fov_y_deg: float = 60.0
    #: keep the eye this far from walls and furniture footprints, metres
    clearance: float = 0.45
    #: candidates looking at a wall closer than this (metres, along the view) are dropped when others remain
    #: (our addition to the paper's recipe: keeps the view from ending up pressed against a wall)
    min_view_depth: float = 1.8


def look_along(eye: np.ndarray, forward: np.ndarray, world_up: list[float]) -> np.ndarray:
    """OpenGL camera-to-world (4, 4) at `eye` looking along the unit vector `forward` (the camera's -z), its +y
    as close to `world_up` as the view allows."""
    x = np.cross(forward, world_up)
    x /= np.linalg.norm(x)
    y = np.cross(x, forward)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, -forward, eye
    return m


def look_matrix(pos: np.ndarray, yaw: float, pitch: float) -> np.ndarray:
    """OpenGL camera-to-world (4, 4): camera looks along (cos p cos y, sin p, cos p sin y), +Y up."""
    return look_along(pos, np.array([np.cos(pitch) * np.cos(yaw), np.sin(pitch), np.cos(pitch) * np.sin(yaw)]), [0.0, 1.0, 0.0])


def free(scene: Scene, xz: np.ndarray, clearance: float) -> np.ndarray:
    """(N,) bool: floor points (N, 2) at least `clearance` from the walls and from every furniture footprint."""
    x, z = xz[:, 0], xz[:, 1]
    ok = (x > clearance) & (x < scene.width - clearance) & (z > clearance) & (z < scene.depth - clearance)
    for x0, z0, x1, z1 in scene.obstacles:
        ok &= ~((x > x0 - clearance) & (x < x1 + clearance) & (z > z0 - clearance) & (z < z1 + clearance))
    return ok


def wall_distance(scene: Scene, xz: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N,) distance from floor points (N, 2) to the room's walls along the horizontal view directions yaw (N,)."""
    f = np.stack([np.cos(yaw), np.sin(yaw)], 1)
    size = np.array([scene.width, scene.depth])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(f > 1e-9, (size - xz) / f, np.where(f < -1e-9, -xz / f, np.inf))
    return t.min(1)


def _object_points(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Centre and 8 corners of every furniture object: points (M, 9, 3) and their object ids (M,)."""
    pts, ids = [], []
    for o in scene.objects:
        if o.category in ("floor", "walls", "ceiling"):
            continue
        lo, hi = o.lo, o.hi
        c = [(lo + hi) / 2] + [np.array([a[0], b[1], e[2]]) for a in (lo, hi) for b in (lo, hi) for e in (lo, hi)]
        pts.append(np.stack(c))
        ids.append(o.id)
    return np.array(pts), np.array(ids)


def visible_counts(scene: Scene, pos: np.ndarray, yaw: np.ndarray, pitch: float, fov_y_deg: float, aspect: float,
                   points: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(N,) number of objects with a point inside the view frustum of each candidate (pos (N, 3), yaw (N,))."""
    pts, _ = points if points is not None else _object_points(scene)
    if len(pts) == 0:
        return np.zeros(len(pos), int)
    f = np.stack([np.cos(pitch) * np.cos(yaw), np.full_like(yaw, np.sin(pitch)), np.cos(pitch) * np.sin(yaw)], 1)  # (N, 3)
    right = np.stack([-np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], 1)  # (N, 3) = normalize(f x up)
    up = np.cross(right, f)
    rel = pts[None] - pos[:, None, None, :]  # (N, M, 9, 3)
    zc = np.einsum("nmkc,nc->nmk", rel, f)
    xc = np.einsum("nmkc,nc->nmk", rel, right)
    yc = np.einsum("nmkc,nc->nmk", rel, up)
    ty = np.tan(np.radians(fov_y_deg) / 2)
    inside = (zc > 0.2) & (np.abs(yc) < ty * zc) & (np.abs(xc) < ty * aspect * zc)
    return inside.any(2).sum(1)


def _bspline(p: np.ndarray, n: int) -> np.ndarray:
    """Uniform cubic B-spline (C2, cuts corners: no kinks) with the rows of p (K, D) as control points, ends
    clamped by tripled end points, n samples per segment: (n*(K+1)+1, D)."""
    q = np.concatenate([p[:1], p[:1], p, p[-1:], p[-1:]])
    t = np.linspace(0, 1, n, endpoint=False)[:, None]
    b0, b1 = (1 - t) ** 3 / 6, (3 * t**3 - 6 * t**2 + 4) / 6
    b2, b3 = (-3 * t**3 + 3 * t**2 + 3 * t + 1) / 6, t**3 / 6
    out = [b0 * q[i] + b1 * q[i + 1] + b2 * q[i + 2] + b3 * q[i + 3] for i in range(len(q) - 3)]
    out.append(p[-1:])
    return np.concatenate(out)


def camera_path(scene: Scene, num_frames: int, aspect: float, seed: int, cfg: PathConfig | None = None) -> list[CameraPose]:
    """A smooth, collision-free camera path of `num_frames` poses through `scene` (deterministic for `seed`)."""
    cfg = cfg or PathConfig()
    rng = np.random.default_rng([seed, 7])
    points = _object_points(scene)
    centre = np.array([scene.width / 2, scene.depth / 2])
    need = cfg.speed * max(num_frames - 1, 1)
    for attempt in range(12):
        start = scene.starts[attempt % len(scene.starts)][[0, 2]].astype(np.float64)
        if not free(scene, start[None], cfg.clearance)[0]:
            continue
        to_c = centre - start
        yaw = float(np.arctan2(to_c[1], to_c[0]))
        heading = yaw
        pitch = float(np.radians(rng.uniform(*cfg.pitch)))
        way, yaws, length, dead = [start], [yaw], 0.0, 0
        while length < need + cfg.step and dead < 3 and len(way) < 200:
            cur = way[-1]
            bend = np.radians(min(cfg.max_bend * (1 + dead), 150.0))  # widen the search after a dead end
            ang = heading + rng.uniform(-bend, bend, cfg.candidates)
            rad = cfg.step * rng.uniform(0.7, 1.3, cfg.candidates)
            cand = cur + np.stack([np.cos(ang), np.sin(ang)], 1) * rad[:, None]
            cyaw = yaws[-1] + np.radians(rng.uniform(-cfg.max_turn, cfg.max_turn, cfg.candidates))
            ok = np.ones(cfg.candidates, bool)
            for s in np.linspace(0.25, 1.0, 4):  # the straight segment to the candidate must be free too
                ok &= free(scene, cur + (cand - cur) * s, cfg.clearance)
            if not ok.any():  # dead end: look wider (never straight back: no cusps); give up this start after 3
                dead += 1
                continue
            dead = 0
            roomy = wall_distance(scene, cand, cyaw) > cfg.min_view_depth
            if (ok & roomy).any():
                ok &= roomy
            pos3 = np.concatenate([cand[:, :1], np.full((len(cand), 1), cfg.eye_height), cand[:, 1:]], 1)
            n = visible_counts(scene, pos3[ok], cyaw[ok], pitch, cfg.fov_y_deg, aspect, points)
            wgt = n.astype(np.float64) ** 2  # paper: w_i = N_i^2
            wgt = wgt / wgt.sum() if wgt.sum() > 0 else np.full(len(wgt), 1.0 / len(wgt))
            k = int(rng.choice(len(wgt), p=wgt))
            nxt = cand[ok][k]
            heading = float(np.arctan2(*(nxt - cur)[::-1]))
            length += float(np.linalg.norm(nxt - cur))
            way.append(nxt)
            yaws.append(float(cyaw[ok][k]))
        if len(way) < 2:
            continue
        dense = _bspline(np.column_stack([np.array(way), np.array(yaws)]), 64)  # (S, 3): x, z, yaw
        seg = np.linalg.norm(np.diff(dense[:, :2], axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        if arc[-1] < need:
            continue
        s = np.arange(num_frames) * cfg.speed
        x, z, yw = (np.interp(s, arc, dense[:, i]) for i in range(3))
        if not free(scene, np.stack([x, z], 1), cfg.clearance * 0.8).all():
            continue
        return [CameraPose(look_matrix(np.array([x[i], cfg.eye_height, z[i]]), yw[i], pitch), cfg.fov_y_deg) for i in range(num_frames)]
    # last resort (a crowded room): stand at the first free start and pan slowly
    start = next((s for s in scene.starts if free(scene, s[None, [0, 2]], cfg.clearance)[0]), scene.starts[0])
    yaw0 = float(np.arctan2(*(centre - start[[0, 2]])[::-1]))
    return [CameraPose(look_matrix(np.array([start[0], cfg.eye_height, start[2]]), yaw0 + np.radians(0.5) * i,
                                   np.radians(-10.0)), cfg.fov_y_deg) for i in range(num_frames)]
