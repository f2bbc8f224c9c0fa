"""The data bench.pareto measures: the shots of each size among the data set folders, their first frames and a digest
of them, and Cycles' own renders of the same rooms (in a Blender process of its own)."""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from x2video.io.dataset import shot_dirs


def per_size(values: tuple[int, ...], sizes: list, flag: str) -> list[int]:
    """One value per size from a flag holding one value or one per size."""
    vals = list(values) * len(sizes) if len(values) == 1 else list(values)
    if len(vals) != len(sizes) or min(vals, default=0) < 1:
        raise SystemExit(f"{flag}: one value of at least 1, or one per --sizes entry ({len(sizes)}); got {','.join(map(str, values))}")
    return vals


def parse_sizes(text: str) -> list[tuple[int, int]]:
    from x2video.cli.args import size_arg

    return [tuple(size_arg(s)) for s in text.split(",") if s.strip()]  # (W, H)


def shots_by_size(folders: list[Path], split: str) -> dict[tuple[int, int], list[Path]]:
    """(W, H) -> finished shot folders of that size (sorted), over every data set folder."""
    out: dict[tuple[int, int], list[Path]] = {}
    for f in folders:
        root = f / split if split else f
        if not root.is_dir():
            raise SystemExit(f"--data {f}: no folder {root}")
        for d in shot_dirs(root):
            info = json.loads((d / "shot.json").read_text())
            out.setdefault((int(info["width"]), int(info["height"])), []).append(d)
    return {k: sorted(v, key=lambda p: (p.name, str(p))) for k, v in out.items()}


def cycles_job(shot_dir: Path, frames: int) -> dict | None:
    """What a Cycles process needs to rebuild this room (None: not a procedural room of `x2video.cycles`)."""
    from x2video.io.metadata import parse_cameras_json

    info = json.loads((shot_dir / "shot.json").read_text())
    extra = info.get("extra", {})
    if "room_seed" not in extra or "light_gain" not in extra or not (shot_dir / "cameras.json").is_file():
        return None
    poses = parse_cameras_json(shot_dir / "cameras.json", int(info["num_frames"]))
    return {"dir": str(shot_dir), "seed": int(extra["room_seed"]), "gain": float(extra["light_gain"]),
            "poses": [(np.asarray(p.cam_to_world, float).tolist(), p.fov_y_deg) for p in poses[:frames]],
            "width": int(info["width"]), "height": int(info["height"]), "samples": extra.get("samples"),
            "version": 3 if str(extra.get("generator", "")).endswith("v3") else 2}


def frames_sha256(shots: list, nframes: list[int]) -> str:
    """A digest of the frames a run renders and scores: every channel the model reads and the data set's rgb, per
    shot and frame (float32 bytes), so that a merge can tell the same data from data rebuilt under the same names."""
    import hashlib

    h = hashlib.sha256()
    for s, n in zip(shots, nframes):
        for t in range(n):
            for c in ("albedo", "normal", "roughness", "metallic", "irradiance", "rgb"):
                if s.has(c):
                    h.update(c.encode())
                    h.update(np.ascontiguousarray(s.channel(c, t), np.float32).tobytes())
    return h.hexdigest()


def images_sha256(shots: list[list[np.ndarray]]) -> str:
    """A digest of display images at 8 bits (a reference render: exact where Cycles and OIDN repeat themselves)."""
    import hashlib

    h = hashlib.sha256()
    for frames in shots:
        for f in frames:
            h.update(np.round(np.clip(f, 0, 1) * 255).astype(np.uint8).tobytes())
    return h.hexdigest()


# --------------------------------------------------------------------------------------------- Cycles (own process)
def _quiet() -> None:
    """Blender prints a line per tile and pass to the C stdout: send it to /dev/null in the worker."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)


def _cycles_worker(jobs: list[dict], samples: list[int], reference: int, threads: int) -> list[dict]:
    """In a Blender process: per job, {samples: (frames, wall seconds, CPU seconds of the process)} for each count
    (seed 0, as the data sets), the reference frames (seed 1) when `reference`, and the scene's build seconds."""
    from x2video.cycles.shot import beauty_scene, render_beauty
    from x2video.shot import CameraPose

    out = []
    warm = False
    for job in jobs:
        poses = [CameraPose(np.array(m, float), fov) for m, fov in job["poses"]]
        t0 = time.perf_counter()
        scene = beauty_scene(job["seed"], poses, job["width"], job["height"], job["gain"], threads=threads, version=job.get("version", 2))
        build = time.perf_counter() - t0
        if not warm:  # kernels and OIDN load on the first render of the process: untimed
            render_beauty(scene, 0, 1)
            warm = True
        res: dict[str, Any] = {"build_seconds": build, "rows": {}}
        for s in samples:
            frames, secs = [], []
            c0 = time.process_time()
            for t in range(len(poses)):
                img, sec = render_beauty(scene, t, s, seed=0)
                frames.append(img)
                secs.append(sec)
            res["rows"][s] = (frames, sum(secs), time.process_time() - c0)
        if reference:
            res["reference"] = [render_beauty(scene, t, reference, seed=1)[0] for t in range(len(poses))]
        out.append(res)
    return out


def run_cycles(jobs: list[dict], samples: list[int], reference: int, threads: int) -> list[dict]:
    """`_cycles_worker` in a spawned process (bpy wants a process of its own)."""
    with mp.get_context("spawn").Pool(1, initializer=_quiet) as pool:
        return pool.apply(_cycles_worker, (jobs, samples, reference, threads))


def bpy_available() -> str | None:
    """None when Blender's Python module can be imported, else why not."""
    import importlib.util

    try:
        return None if importlib.util.find_spec("bpy") is not None else "bpy is not installed (pip install 'x2video-studio[cycles]')"
    except (ImportError, ValueError) as exc:
        return f"bpy: {exc}"
