"""Keyframe shots: Cycles renders the full frame on keyframes only and G-buffer passes on the frames between.

A keyframe holds everything a full export holds (Combined, the light passes, the AOVs). A G-buffer frame holds
the AOVs (base colour, roughness, metallic), Normal, Depth, object index and Emit + Env, rendered with few
samples, no bounces and no denoiser, all G-buffer frames in as few animation renders as their spacing allows,
with ``use_persistent_data`` so that Blender keeps the scene between frames. Both costs are measured per frame.
"""

import os
import shutil
import tempfile
import time
from contextlib import contextmanager

#: the render-layer outputs a G-buffer frame writes (the AOVs are added by `compositor_output`)
GBUFFER_PASSES = ("Emit", "Env", "Normal", "IndexOB", "Depth")
#: the view-layer flags a G-buffer frame renders with (every other pass flag of ours is off)
GBUFFER_FLAGS = ("use_pass_z", "use_pass_normal", "use_pass_object_index", "use_pass_emit", "use_pass_environment")
#: path-tracing samples of a G-buffer frame: one, at each pixel's centre (a G-buffer's cost is its samples: 4 cost 4x,
#: bench/results/keyframes/gbuffer_cost.json); more give anti-aliased edges
GBUFFER_SAMPLES = 1


def keyframe_list(num_frames, every=0, frames=""):
    """The keyframes of a shot of `num_frames` frames (shot indices, from 0), or None when every frame is one.

    every=N: frames 0, N, 2N, ... and the last frame (so that no frame lies after the last keyframe);
    frames: an explicit list "0, 8, 16" (shot indices). Both empty: None."""
    if frames and str(frames).strip():
        try:
            keys = sorted({int(f) for f in str(frames).replace(",", " ").split()})
        except ValueError:
            raise ValueError("keyframes %r: expected frame numbers such as '0, 8, 16'" % (frames,)) from None
        bad = [f for f in keys if not 0 <= f < num_frames]
        if bad:
            raise ValueError("keyframes %s lie outside the shot's frames 0..%d" % (bad, num_frames - 1))
        return keys
    if every and every > 1:
        return sorted(set(range(0, num_frames, int(every))) | {num_frames - 1})
    if every and every < 0:
        raise ValueError("keyframe_every must be 0 (every frame is a keyframe) or N >= 1, got %d" % every)
    return None


def runs(frames):
    """Sorted frames as (first, last, step) runs, each one animation render: the fewer of consecutive runs or
    one run per residue of the most common gap (the frames between keyframes every N are N-1 strided runs)."""
    frames = sorted(frames)
    if not frames:
        return []
    consecutive = []
    for f in frames:
        if consecutive and f == consecutive[-1][1] + 1:
            consecutive[-1][1] = f
        else:
            consecutive.append([f, f])
    best = [(a, b, 1) for a, b in consecutive]
    period = consecutive[1][0] - consecutive[0][0] if len(consecutive) > 1 else 0
    if period > 1:
        strided, rest = {}, []
        for f in frames:
            strided.setdefault(f % period, []).append(f)
        for group in strided.values():  # a residue's frames form one run only where none is missing between them
            if group == list(range(group[0], group[-1] + 1, period)):
                rest.append((group[0], group[-1], period))
            else:
                rest = None
                break
        if rest is not None and len(rest) < len(best):
            best = sorted(rest)
    return best


@contextmanager
def gbuffer_settings(scene, layer, samples=GBUFFER_SAMPLES):
    """The scene set to render G-buffers: `samples` samples, no bounces, no denoiser, no adaptive sampling, no light
    tree (its build and traversal cost a third of a G-buffer frame, and no light is needed), only the G-buffer passes
    (and the AOVs) on `layer`, persistent data on; one sample is taken at the pixel's centre (a jittered single
    sample would make edges flicker). Everything is put back on exit."""
    from .passes import PASS_FLAGS

    c = scene.cycles
    want = [(c, "samples", int(samples)), (c, "max_bounces", 0), (c, "use_denoising", False), (c, "use_adaptive_sampling", False),
            (c, "use_light_tree", False), (layer.cycles, "use_denoising", False), (layer.cycles, "denoising_store_passes", False),
            (scene.render, "use_persistent_data", True)]
    if samples == 1:
        want.append((c, "filter_width", 0.01))
    for flag in PASS_FLAGS:
        want.append((layer if hasattr(layer, flag) else layer.cycles, flag, flag in GBUFFER_FLAGS))
    saved = []
    for owner, key, value in want:
        if hasattr(owner, key):  # Blender 3.4 has no light tree
            saved.append((owner, key, getattr(owner, key)))
            setattr(owner, key, value)
    try:
        yield
    finally:
        for owner, key, value in reversed(saved):
            setattr(owner, key, value)


def render_frames(scene, file_out, directory, frames, first):
    """Render Blender frames `first + t` for shot indices `frames` through the File Output node `file_out` into
    DIRECTORY/frame_<t>.exr, as animation renders over `runs`. Returns {t: (wall seconds, CPU seconds)}: each
    frame's share of its run, measured between Blender's render_post events (a run's set-up counts in its first)."""
    import bpy  # here, so that the frame choice above can be tested without Blender

    keep = (scene.frame_start, scene.frame_end, scene.frame_step, scene.render.filepath, scene.render.image_settings.file_format)
    stamps = []

    def stamp(*_):
        stamps.append((time.perf_counter(), time.process_time()))

    cost = {}
    bpy.app.handlers.render_post.append(stamp)
    try:
        for a, b, step in runs(first + t for t in frames):
            tmp = tempfile.mkdtemp(prefix=".tmp_", dir=directory)
            try:
                file_out.base_path = os.path.join(tmp, "frame_")
                scene.render.filepath = os.path.join(tmp, "still_")
                scene.render.image_settings.file_format = "PNG"  # the Composite output Blender writes too: cheap
                scene.frame_start, scene.frame_end, scene.frame_step = a, b, step
                del stamps[:]
                t0 = (time.perf_counter(), time.process_time())
                bpy.ops.render.render(animation=True)
                for i, f in enumerate(range(a, b + 1, step)):
                    src = os.path.join(tmp, "frame_%04d.exr" % f)
                    if not os.path.isfile(src):
                        raise RuntimeError("Blender wrote no file for frame %d (the render failed: see Blender's console)" % f)
                    os.replace(src, os.path.join(directory, "frame_%04d.exr" % (f - first)))
                    prev = t0 if i == 0 else stamps[i - 1]
                    end = stamps[i] if i < len(stamps) else (time.perf_counter(), time.process_time())
                    cost[f - first] = (end[0] - prev[0], end[1] - prev[1])
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
    finally:
        bpy.app.handlers.render_post.remove(stamp)
        scene.frame_start, scene.frame_end, scene.frame_step, scene.render.filepath = keep[:4]
        scene.render.image_settings.file_format = keep[4]
    return cost
