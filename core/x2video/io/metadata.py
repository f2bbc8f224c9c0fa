"""Shot metadata as JSON, the one home of its parsing and writing: shot.json (docs/SHOT_FORMAT.md) and the
camera files (our cameras.json, or a nerfstudio / instant-ngp transforms.json).

Every loader reads these documents through here and every writer builds them here; `read_json` is the JSON
read with errors naming the file that the project files use too.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from x2video.shot import CameraPose, ShotInfo

log = logging.getLogger(__name__)

FORMAT_NAME = "x2video-shot"
FORMAT_VERSION = 1
_SHOT_KEYS = {
    "format", "version", "num_frames", "width", "height", "fps", "caption", "objects", "irradiance_normalized", "extra", "keyframes",
}


def shot_json(info: ShotInfo, irradiance_normalized: bool = True) -> dict[str, Any]:
    """The shot.json document describing `info`."""
    return {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "num_frames": int(info.num_frames),
        "width": int(info.width),
        "height": int(info.height),
        "fps": float(info.fps),
        "caption": info.caption,
        "objects": {str(k): v for k, v in sorted(info.object_captions.items())},
        "irradiance_normalized": bool(irradiance_normalized),
        "extra": _jsonable(info.extra, "extra"),
    }


def cameras_json(poses: list[CameraPose]) -> dict[str, Any]:
    """The cameras.json document for per-frame `poses`."""
    frames = []
    for t, p in enumerate(poses):
        m = np.asarray(p.cam_to_world, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"camera pose of frame {t}: cam_to_world has shape {m.shape}, expected (4, 4)")
        entry: dict[str, Any] = {"frame": t, "cam_to_world": m.tolist()}
        if p.fov_y_deg is not None:
            entry["fov_y_deg"] = float(p.fov_y_deg)
        frames.append(entry)
    return {"convention": "opengl_cam_to_world", "frames": frames}


def read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text ({exc})") from None


def parse_shot_json(path: Path) -> dict[str, Any]:
    """Read and check shot.json; returns the document (missing optional fields filled in)."""
    doc = read_json(path)
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a JSON object")
    if doc.get("format", FORMAT_NAME) != FORMAT_NAME:
        raise ValueError(f"{path}: field 'format' is {doc.get('format')!r}, expected {FORMAT_NAME!r}")
    version = doc.get("version", FORMAT_VERSION)
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise ValueError(f"{path}: field 'version' is {version!r}; this x2video reads shot folders up to version {FORMAT_VERSION}")
    unknown = set(doc) - _SHOT_KEYS
    if unknown:
        log.warning("%s: ignoring unknown field(s) %s", path, ", ".join(sorted(unknown)))
    for key in ("num_frames", "width", "height"):
        if key in doc and (not isinstance(doc[key], int) or doc[key] <= 0):
            raise ValueError(f"{path}: field {key!r} must be a positive integer, got {doc[key]!r}")
    if "fps" in doc and (not isinstance(doc["fps"], (int, float)) or doc["fps"] <= 0):
        raise ValueError(f"{path}: field 'fps' must be a positive number, got {doc['fps']!r}")
    objects = doc.get("objects", {})
    if not isinstance(objects, dict):
        raise ValueError(f"{path}: field 'objects' must map object ids to captions")
    try:
        doc["objects"] = {int(k): str(v) for k, v in objects.items()}
    except ValueError:
        raise ValueError(f"{path}: field 'objects' has a key that is not an integer object id: {list(objects)}") from None
    if not isinstance(doc.get("extra", {}), dict):
        raise ValueError(f"{path}: field 'extra' must be a JSON object")
    keys = doc.get("keyframes")
    if keys is not None and not (isinstance(keys, list) and keys and all(isinstance(k, int) and not isinstance(k, bool) and k >= 0 for k in keys)
                                 and keys == sorted(set(keys))):
        raise ValueError(f"{path}: field 'keyframes' must list the frames that carry rgb, increasing from 0 (e.g. [0, 8, 16]), got {keys!r}")
    return doc


#: the two camera files a shot folder may hold, in order of preference
POSE_FILES = ("cameras.json", "transforms.json")
POSE_FORMS = (
    "our cameras.json {'convention': 'opengl_cam_to_world', 'frames': [{'frame': 0, 'cam_to_world': 4x4, 'fov_y_deg': 60}]}"
    " or a nerfstudio / instant-ngp transforms.json {'frames': [{'file_path': ..., 'transform_matrix': 4x4}],"
    " 'fl_y'/'h' or 'camera_angle_x'}"
)


def find_poses(folder: Path, num_frames: int, size: tuple[int, int] | None = None) -> list[CameraPose] | None:
    """Per-frame poses from `folder`'s cameras.json or transforms.json (the first present), or None.

    `size` (H, W) of the frames lets a transforms.json with only `camera_angle_x` give a vertical fov."""
    for name in POSE_FILES:
        path = Path(folder) / name
        if path.is_file():
            return read_poses(path, num_frames, size)
    return None


def read_poses(path: Path, num_frames: int, size: tuple[int, int] | None = None) -> list[CameraPose]:
    """Poses from either camera file form, told apart by content; an error naming both forms otherwise."""
    doc = read_json(path)
    frames = doc.get("frames") if isinstance(doc, dict) else None
    if isinstance(frames, list) and frames and all(isinstance(f, dict) and "transform_matrix" in f for f in frames):
        return parse_transforms_json(path, num_frames, size, doc)
    if isinstance(frames, list) and all(isinstance(f, dict) and "cam_to_world" in f for f in frames):
        return parse_cameras_json(path, num_frames)
    raise ValueError(f"{path}: not a camera file this x2video reads; expected {POSE_FORMS}")


def _frame_order(frames: list[dict[str, Any]]) -> list[int]:
    """Indices of transforms.json frames in shot order: by the number in each file name (nerfstudio sorts
    by file name too), else as listed."""
    import re

    nums = []
    for f in frames:
        m = re.search(r"(\d+)(?!.*\d)", Path(str(f.get("file_path", ""))).stem)
        nums.append(None if m is None else int(m.group(1)))
    if all(n is not None for n in nums) and len(set(nums)) == len(nums):
        return sorted(range(len(frames)), key=lambda i: nums[i])  # type: ignore[arg-type, return-value]
    return list(range(len(frames)))


def parse_transforms_json(path: Path, num_frames: int, size: tuple[int, int] | None = None, doc: Any = None) -> list[CameraPose]:
    """A nerfstudio / instant-ngp transforms.json: `frames[].transform_matrix` is camera-to-world with an
    OpenGL camera (as ours); the vertical fov comes from `fl_y` and `h` (per frame or top level), else
    `camera_angle_y`, else `camera_angle_x` with the aspect ratio (`w`/`h`, else the frames' size)."""
    import math

    doc = read_json(path) if doc is None else doc
    frames = doc["frames"]
    if len(frames) != num_frames:
        raise ValueError(f"{path}: {len(frames)} frames in transforms.json for a shot of {num_frames} frames")
    poses = []
    for i in _frame_order(frames):
        f = frames[i]
        try:
            m = np.asarray(f["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{path}: frames[{i}].transform_matrix is not a matrix") from None
        if m.shape == (3, 4):
            m = np.vstack([m, [0, 0, 0, 1]])
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise ValueError(f"{path}: frames[{i}].transform_matrix is not a finite 4x4 matrix (shape {m.shape})")

        def get(key: str, f: dict[str, Any] = f) -> float | None:
            v = f.get(key, doc.get(key))
            return None if v is None else float(v)

        fl_y, fl_x, h, w = get("fl_y"), get("fl_x"), get("h"), get("w")
        h = h if h is not None else (None if size is None else float(size[0]))
        w = w if w is not None else (None if size is None else float(size[1]))
        fov = None
        if (fl_y or fl_x) and h:
            fov = 2 * math.atan(h / (2 * (fl_y or fl_x)))  # type: ignore[operator]
        elif get("camera_angle_y") is not None:
            fov = get("camera_angle_y")
        elif get("camera_angle_x") is not None and h and w:
            fov = 2 * math.atan(math.tan(get("camera_angle_x") / 2) * h / w)  # type: ignore[operator]
        poses.append(CameraPose(cam_to_world=m, fov_y_deg=None if fov is None else math.degrees(fov)))
    return poses


def parse_cameras_json(path: Path, num_frames: int) -> list[CameraPose]:
    """Read cameras.json; one pose per frame, in frame order."""
    doc = read_json(path)
    frames = doc.get("frames") if isinstance(doc, dict) else None
    if not isinstance(frames, list):
        raise ValueError(f"{path}: not a camera file this x2video reads; expected {POSE_FORMS}")
    conv = doc.get("convention", "opengl_cam_to_world")
    if conv != "opengl_cam_to_world":
        raise ValueError(f"{path}: field 'convention' is {conv!r}, expected 'opengl_cam_to_world'")
    poses: dict[int, CameraPose] = {}
    for i, f in enumerate(frames):
        try:
            t = int(f.get("frame", i))
            m = np.asarray(f["cam_to_world"], dtype=np.float64)
        except (KeyError, TypeError, ValueError, AttributeError):
            raise ValueError(f"{path}: frames[{i}] needs 'frame' and a 4x4 'cam_to_world'") from None
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise ValueError(f"{path}: frames[{i}].cam_to_world is not a finite 4x4 matrix (shape {m.shape})")
        fov = f.get("fov_y_deg")
        poses[t] = CameraPose(cam_to_world=m, fov_y_deg=None if fov is None else float(fov))
    missing = [t for t in range(num_frames) if t not in poses]
    if missing:
        raise ValueError(f"{path}: no camera pose for frame(s) {missing[:5]}{'...' if len(missing) > 5 else ''} of {num_frames}")
    return [poses[t] for t in range(num_frames)]


def _jsonable(obj: Any, where: str) -> Any:
    try:
        return json.loads(json.dumps(obj))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"ShotInfo.{where} is not JSON-serialisable: {exc}") from None
