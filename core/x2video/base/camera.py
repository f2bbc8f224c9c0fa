"""Pinhole geometry of a shot's frames: pixels to camera space by depth, and into another frame's view.

The convention is the shot's (docs/SHOT_FORMAT.md): `CameraPose.cam_to_world` is OpenGL (the camera looks down
-Z, +Y up, +X right), depth is the view-space distance along -Z, pixel (x, y) has its centre at (x + 0.5, y + 0.5)
with y down, and the principal point is the frame's centre.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from x2video.shot import CameraPose


@dataclass(frozen=True)
class View:
    """One frame's camera: pose (4x4 camera-to-world) and intrinsics for an (H, W) frame."""

    cam_to_world: np.ndarray
    focal: float  # pixels
    height: int
    width: int

    @classmethod
    def of(cls, pose: CameraPose, size: tuple[int, int]) -> View:
        if pose.fov_y_deg is None:
            raise ValueError("a camera pose without fov_y_deg cannot reproject (cameras.json needs fov_y_deg)")
        h, w = size
        return cls(np.asarray(pose.cam_to_world, np.float64), (h / 2) / math.tan(math.radians(pose.fov_y_deg) / 2), h, w)

    @property
    def rotation(self) -> np.ndarray:
        return self.cam_to_world[:3, :3]


def unproject(view: View, depth: np.ndarray) -> np.ndarray:
    """(H, W, 3) world positions of every pixel of `view` at its `depth` (H, W) (distance along -Z)."""
    h, w = depth.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    d = np.asarray(depth, np.float64).reshape(h, w)
    cam = np.stack([(xs + 0.5 - w / 2) / view.focal * d, -(ys + 0.5 - h / 2) / view.focal * d, -d], -1)  # (H, W, 3)
    return cam @ view.rotation.T + view.cam_to_world[:3, 3]


def project(view: View, world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World positions (H, W, 3) seen by `view`: (x, y) pixel coordinates (sample positions, centre at .5 offsets
    removed, i.e. what cv2.remap takes) and their depth along -Z (<= 0: behind the camera)."""
    world_to_cam = np.linalg.inv(view.cam_to_world)
    cam = world @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]  # (H, W, 3)
    d = -cam[..., 2]
    safe = np.where(d > 1e-6, d, 1e-6)
    x = cam[..., 0] / safe * view.focal + view.width / 2 - 0.5
    y = -cam[..., 1] / safe * view.focal + view.height / 2 - 0.5
    return x.astype(np.float32), y.astype(np.float32), d.astype(np.float32)


def world_normals(view: View, normal_cam: np.ndarray) -> np.ndarray:
    """Camera-space unit normals (H, W, 3) of `view` in world space."""
    return (np.asarray(normal_cam, np.float64) @ view.rotation.T).astype(np.float32)
