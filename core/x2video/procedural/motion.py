"""Exact per-pixel motion between consecutive frames from depth and camera poses (for the TC metric), NaN where occluded."""
from __future__ import annotations

import numpy as np

from x2video.shot import CameraPose


def _rays(h: int, w: int, fov_y_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Camera-space x/y per unit depth of every pixel centre (H, W) each; image rows top to bottom."""
    ty = np.tan(np.radians(fov_y_deg) / 2)
    tx = ty * w / h
    xs = ((np.arange(w) + 0.5) / w * 2 - 1) * tx
    ys = (1 - (np.arange(h) + 0.5) / h * 2) * ty
    return np.broadcast_to(xs[None, :], (h, w)), np.broadcast_to(ys[:, None], (h, w))


def unproject(depth: np.ndarray, pose: CameraPose) -> np.ndarray:
    """World positions (H, W, 3) of the pixels of a view-space depth map (H, W) or (H, W, 1)."""
    d = np.asarray(depth, np.float64).reshape(depth.shape[0], depth.shape[1])
    rx, ry = _rays(*d.shape, pose.fov_y_deg or 60.0)
    cam = np.stack([rx * d, ry * d, -d, np.ones_like(d)], -1)  # (H, W, 4)
    return (cam @ np.asarray(pose.cam_to_world, np.float64).T)[..., :3]


def project(points: np.ndarray, pose: CameraPose, h: int, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel coordinates x, y (continuous, pixel centres at integer + 0.5 minus 0.5 = integers) and view depth of world points (..., 3)."""
    w2c = np.linalg.inv(np.asarray(pose.cam_to_world, np.float64))
    p = points @ w2c[:3, :3].T + w2c[:3, 3]
    depth = -p[..., 2]
    ty = np.tan(np.radians(pose.fov_y_deg or 60.0) / 2)
    tx = ty * w / h
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc_x = p[..., 0] / (depth * tx)
        ndc_y = p[..., 1] / (depth * ty)
    return (ndc_x + 1) / 2 * w - 0.5, (1 - ndc_y) / 2 * h - 0.5, depth


def motion_field(depth_t: np.ndarray, pose_t: CameraPose, depth_t1: np.ndarray, pose_t1: CameraPose,
                 rel_tol: float = 0.02, near: float = 0.05) -> np.ndarray:
    """(H, W, 2) float32 displacement (x right, y down, pixels) of each pixel of frame t in frame t+1.

    NaN where the point leaves the view, has no geometry (depth <= 0) or is hidden in frame t+1 (no depth
    sample of frame t+1 around the landing spot within `rel_tol` of the point's depth there)."""
    d0 = np.asarray(depth_t, np.float64).reshape(depth_t.shape[0], depth_t.shape[1])
    d1 = np.asarray(depth_t1, np.float64).reshape(d0.shape)
    h, w = d0.shape
    world = unproject(d0, pose_t)
    x1, y1, z1 = project(world, pose_t1, h, w)
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    flow = np.stack([x1 - gx, y1 - gy], -1)
    ok = (d0 > 0) & (z1 > near) & (x1 >= -0.5) & (x1 <= w - 0.5) & (y1 >= -0.5) & (y1 <= h - 0.5)
    x1c, y1c = np.where(ok, x1, 0.0), np.where(ok, y1, 0.0)
    seen = np.zeros_like(ok)
    for ox in (0, 1):  # visible if any of the 2x2 neighbours of the landing spot holds this surface
        for oy in (0, 1):
            xi = np.clip(np.floor(x1c).astype(int) + ox, 0, w - 1)
            yi = np.clip(np.floor(y1c).astype(int) + oy, 0, h - 1)
            seen |= np.abs(d1[yi, xi] - z1) <= rel_tol * z1 + 0.005
    flow[~(ok & seen)] = np.nan
    return flow.astype(np.float32)
