"""The live preview of an edit over a shot's path-traced frames (issue 52), without the GUI: `python -m bench.editor_latency
--base-fps` (bench/results/editor_latency/editor_latency_base.json).

Frames/s of tier 0's difference (an albedo recolour) and tier 1's (a roughness raised: the formula's difference plus
tier 1's where gloss changed; a surface made glossier keeps the formula's, `x2video.base.difference.sharpened`, so
the net would not run) at 320x224, as the editor's worker renders them (`x2video.render.live.render_frame` on one
`Renderer`, base 'auto', the edit's value changed each frame as a slider drag does): on an object (a sofa, 100x160
pixels of the frame) over a path-traced frame and over a frame filled from keyframes 1 in 4 (the fill runs too), a
small object (a vase, 40x30), and the worst case, an edit of the whole frame. The tier-1 net is an untrained one of the
default architecture (its cost does not depend on its weights) run by the engine the editor loads it with
(`x2video.model.residual_engine.engine`: ONNX Runtime where installed), on `threads` threads as the editor runs it on
two cores (`x2video_app`'s `set_render_threads`). Each row: the median of `repeats` frames after one warm-up (the
warm-up pays for what the live preview keeps between frames: the original frame's part), wall and CPU seconds a
frame, and the Renderer's 'residual' stage (0 calls: the net did not run).
"""
from __future__ import annotations

import os
import time

#: issue 52: the live preview of an edit as a difference over a shot's path-traced frames, frames/s at 320x224
BASE_TARGET_FPS = 10.0
#: the edited region: its rows and columns in a 224x320 frame (scaled with the frame)
OBJECTS = {"object (sofa, 100x160)": ((80, 180), (100, 260)),
           "small object (vase, 40x30)": ((120, 160), (200, 230)),
           "whole frame (worst case)": ((0, 224), (0, 320))}


def object_slices(edit: str, size: tuple[int, int]) -> tuple[slice, slice]:
    """`OBJECTS[edit]` in a frame of `size` (H, W)."""
    (y0, y1), (x0, x1) = OBJECTS[edit]
    h, w = size
    return slice(y0 * h // 224, max(y1 * h // 224, y0 * h // 224 + 1)), slice(x0 * w // 320, max(x1 * w // 320, x0 * w // 320 + 1))


def base_difference_fps(repeats: int = 20, size: tuple[int, int] = (224, 320), threads: int = 1) -> list[dict]:
    """The rows of the module docstring, printed as they finish."""
    import numpy as np
    import torch

    from x2video.base.keyframes import only_keyframes
    from x2video.edits import Edits
    from x2video.edits.masks import Mask
    from x2video.model.pipeline import X2VideoModel
    from x2video.model.residual import ResidualConfig, ResidualNet
    from x2video.model.residual_engine import engine
    from x2video.render.live import render_frame
    from x2video.render.renderer import Renderer
    from x2video.render.settings import RenderSettings
    from x2video.render.timing import StageTimes
    from x2video.shot import ArrayShot

    torch.set_num_threads(threads)
    h, w = size
    n = 9
    rng = np.random.default_rng(0)
    albedo = rng.uniform(0.1, 0.9, (n, h, w, 3)).astype(np.float32)
    irr = np.broadcast_to(np.linspace(0.3, 2.0, w, dtype=np.float32)[None, None, :, None], (n, h, w, 3)).copy()
    normal = np.zeros((n, h, w, 3), np.float32)
    normal[..., 2] = 1
    depth = np.full((n, h, w, 1), 4.0, np.float32)
    rgb = albedo * irr
    rgb[:, 10:60, 20:120] += 3.0  # a window the channels do not hold
    shot = ArrayShot({"albedo": albedo, "irradiance": irr, "normal": normal, "rgb": rgb, "depth": depth,
                      "roughness": np.full((n, h, w, 1), 0.6, np.float32), "metallic": np.zeros((n, h, w, 1), np.float32)},
                     irradiance_scale=0.5)
    keyed = only_keyframes(shot, "every:4")
    model = X2VideoModel.untrained("tiny")
    model.residual_net = engine(ResidualNet(ResidualConfig()).eval(), "cpu")
    net_engine = type(model.residual_net).__name__

    def edits(kind: str, where: tuple[slice, slice], k: int) -> Edits:
        mask = np.zeros((h, w), np.float32)
        mask[where] = 1
        e = Edits()
        e.masks["object"] = Mask(frames={0: mask}, hold=True)
        if kind == "albedo":
            e.set_tuning("object", "albedo_colour", (0.9, 0.1 + 0.02 * (k % 20), 0.1))
        else:  # rougher than the shot's 0.6: tier 1's difference (glossier keeps the formula's)
            e.set_tuning("object", "roughness_mode", "set")
            e.set_tuning("object", "roughness", 0.7 + 0.01 * (k % 20))
        return e

    cases = [("tier 0 (formula)", "albedo", "formula", "object (sofa, 100x160)", "path-traced frame", shot, 4),
             ("tier 0 (formula)", "albedo", "formula", "object (sofa, 100x160)", "filled frame (keyframes every:4)", keyed, 2),
             ("tier 1 (formula+residual)", "roughness", "auto", "object (sofa, 100x160)", "path-traced frame", shot, 4),
             ("tier 1 (formula+residual)", "roughness", "auto", "object (sofa, 100x160)", "filled frame (keyframes every:4)", keyed, 2),
             ("tier 1 (formula+residual)", "roughness", "auto", "small object (vase, 40x30)", "path-traced frame", shot, 4),
             ("tier 1 (formula+residual)", "roughness", "auto", "whole frame (worst case)", "path-traced frame", shot, 4)]
    rows = []
    for tier, kind, quality, edit, label, s, t in cases:
        renderer = Renderer(model)
        renderer.timing = StageTimes()
        settings = RenderSettings(quality=quality, base="auto")
        secs, cpus, net_s, net_calls, made = [], [], [], 0, None
        for k in range(repeats + 1):
            t0, c0 = time.perf_counter(), time.process_time()
            made = render_frame(renderer, s, edits(kind, object_slices(edit, size), k), settings, t)
            if k:
                secs.append(time.perf_counter() - t0)
                cpus.append(time.process_time() - c0)
                net_s.append(renderer.timing.seconds["residual"])
                net_calls += renderer.timing.calls["residual"]
        assert made is not None
        med = float(np.median(secs))
        rows.append({"difference": tier, "edit": edit, "frame": label, "size": [w, h], "tier_said": made.tier, "frames": repeats,
                     "median_s": round(med, 4), "p95_s": round(float(np.percentile(secs, 95)), 4), "fps": round(1 / med, 1),
                     "cpu_s_per_frame": round(float(np.median(cpus)), 4), "residual_stage_s": round(float(np.median(net_s)), 4),
                     "residual_calls": net_calls, "engine": net_engine if quality != "formula" else None, "threads": threads,
                     "met": 1 / med >= BASE_TARGET_FPS, "load_average": [round(v, 2) for v in os.getloadavg()]})
        print(f"{tier} over the base, {edit}, {label} at {w}x{h}: {rows[-1]['fps']} frames/s (median {med * 1000:.0f} ms, "
              f"p95 {rows[-1]['p95_s'] * 1000:.0f} ms, CPU {rows[-1]['cpu_s_per_frame'] * 1000:.0f} ms, tier 1's net "
              f"{rows[-1]['residual_stage_s'] * 1000:.0f} ms; tier {made.tier}); load {rows[-1]['load_average']}", flush=True)
    return rows
