"""`export_shot`: render a frame range into an X2Video shot folder (EXR frames, cameras.json, shot.json)."""

import json
import math
import os

import bpy

from .keyframes import GBUFFER_PASSES, GBUFFER_SAMPLES, gbuffer_settings, keyframe_list, render_frames
from .passes import _aov_outputs, _input, _principled_nodes, compositor_output, configure_view_layer, denoiser_available, wire_material

#: a dielectric below this roughness is "glossy" (x2video.cycles.classes.GLOSSY_BELOW)
GLOSSY_BELOW = 0.25
FORMAT_NAME, FORMAT_VERSION = "x2video-shot", 1
NO_DENOISER = "this Blender is built without OpenImageDenoise: exporting without denoising (Combined and the light passes as sampled)"


# ------------------------------------------------------------------------------------------------ cameras, classes
def fov_y_deg(scene, cam):
    """The camera's vertical field of view in degrees, with its sensor fit and the render's aspect considered."""
    r, data = scene.render, cam.data
    if data.type != "PERSP":
        raise ValueError("the scene camera must be a perspective camera (it is %s)" % data.type)
    aspect = (r.resolution_x * r.pixel_aspect_x) / float(r.resolution_y * r.pixel_aspect_y)
    fit = data.sensor_fit
    if fit == "AUTO":
        fit, size = ("HORIZONTAL" if aspect >= 1 else "VERTICAL"), data.sensor_width
    else:
        size = data.sensor_width if fit == "HORIZONTAL" else data.sensor_height
    half = size / (2.0 * data.lens)  # tan of the half angle along the fitted side
    if fit == "HORIZONTAL":
        half /= aspect
    return math.degrees(2.0 * math.atan(half))


def cam_to_world(cam):
    """matrix_world without scale (rows): OpenGL cam_to_world (Blender cameras look down -Z, +Y up)."""
    m = cam.matrix_world
    rot = m.to_quaternion().to_matrix()
    t = m.to_translation()
    return [[rot[i][0], rot[i][1], rot[i][2], t[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]


def classify(mat):
    """diffuse / glossy / metal / glass / emitter for a material's first Principled BSDF (None without one)."""
    if mat is None or not mat.use_nodes or mat.node_tree is None:
        return None
    bsdfs = _principled_nodes(mat.node_tree)
    if not bsdfs:
        return "emitter" if any(n.bl_idname == "ShaderNodeEmission" for n in mat.node_tree.nodes) else None
    b = bsdfs[0]

    def value(*names):
        s = _input(b, *names)
        return 0.0 if s is None else (max(tuple(s.default_value)[:3]) if hasattr(s.default_value, "__len__") else float(s.default_value))

    strength = value("Emission Strength") if _input(b, "Emission Strength") is not None else 1.0
    if value("Emission Color", "Emission") * strength > 0:
        return "emitter"
    if value("Metallic") >= 0.5:
        return "metal"
    if value("Transmission Weight", "Transmission") >= 0.5:
        return "glass"
    return "glossy" if value("Roughness") < GLOSSY_BELOW else "diffuse"


def assign_ids(scene):
    """Give every rendered object with pass index 0 a free one (the ids channel tells objects apart)."""
    used = {ob.pass_index for ob in scene.objects}
    nxt = 1
    for ob in scene.objects:
        if ob.type in ("MESH", "CURVE", "SURFACE", "META", "FONT") and ob.pass_index == 0:
            while nxt in used:
                nxt += 1
            ob.pass_index = nxt
            used.add(nxt)


def _objects_and_classes(scene):
    objects, classes = {}, {}
    for ob in scene.objects:
        if ob.pass_index > 0 and ob.type in ("MESH", "CURVE", "SURFACE", "META", "FONT"):
            key = str(ob.pass_index)
            objects[key] = objects[key] + ", " + ob.name if key in objects else ob.name
            mats = [s.material for s in ob.material_slots if s.material is not None]
            cls = [c for c in (classify(m) for m in mats) if c is not None]
            if cls and key not in classes:
                classes[key] = "emitter" if "emitter" in cls else cls[0]
    return objects, classes


def _mean(cost, frames, which):
    vals = [cost[t][which] for t in frames]
    return round(sum(vals) / len(vals), 4) if vals else None


# ------------------------------------------------------------------------------------------------ the export
def export_shot(scene, directory, frame_start, frame_end, denoise=True, caption="", ids=True, report=print,
                keyframe_every=0, keyframes="", gbuffer_samples=GBUFFER_SAMPLES, generator="x2video_export add-on"):
    """Render frames frame_start..frame_end of `scene` into the shot folder `directory`; returns the frame count.

    keyframe_every=N (or `keyframes`, a list "0, 8, 16" of shot frames) makes a keyframe shot: the full render on
    those frames only, G-buffer passes on the others (`keyframes` module)."""
    if scene.camera is None:
        raise ValueError("the scene has no camera")
    if frame_end < frame_start:
        raise ValueError("frame range %d..%d is empty" % (frame_start, frame_end))
    n = frame_end - frame_start + 1
    keys = keyframe_list(n, keyframe_every, keyframes)
    os.makedirs(directory, exist_ok=True)
    if scene.render.engine != "CYCLES":
        report("switching the render engine to Cycles (the light passes are Cycles')")
        scene.render.engine = "CYCLES"
    layer = bpy.context.view_layer if bpy.context.view_layer.name in scene.view_layers else scene.view_layers[0]
    configure_view_layer(scene, layer)
    theirs = sum(1 for m in bpy.data.materials if m.use_nodes and m.node_tree is not None
                 for nd in _aov_outputs(m.node_tree) if not nd.get("x2video_aov"))
    if theirs:
        report("replacing %d AOV output(s) named basecolor/roughness/metallic that materials had: Cycles sums the outputs"
               " of one AOV, ours copy the Principled BSDF's inputs" % theirs)
    wired = sum(1 for m in bpy.data.materials if wire_material(m) > 0)
    if ids:
        assign_ids(scene)
    has_denoiser = denoiser_available()
    if not has_denoiser:  # the scene's own denoising (on by default) would stop the render
        report(NO_DENOISER)
        scene.cycles.use_denoising = layer.cycles.use_denoising = False
        denoise = False
    file_out = compositor_output(scene, layer, denoise_passes=denoise)
    frames, keep = [], scene.frame_current
    key_frames = list(range(n)) if keys is None else keys
    between = sorted(set(range(n)) - set(key_frames))
    try:
        for t in range(n):
            scene.frame_set(frame_start + t)
            frames.append({"frame": t, "cam_to_world": cam_to_world(scene.camera), "fov_y_deg": fov_y_deg(scene, scene.camera)})
        report("rendering %d keyframe(s) at %d samples" % (len(key_frames), scene.cycles.samples) if keys else "rendering %d frame(s)" % n)
        cost = render_frames(scene, file_out, directory, key_frames, frame_start)
        if between:
            with gbuffer_settings(scene, layer, gbuffer_samples):
                report("rendering %d G-buffer frame(s) at %d sample(s), no bounces" % (len(between), gbuffer_samples))
                file_out = compositor_output(scene, layer, denoise_passes=False, passes=GBUFFER_PASSES)
                cost.update(render_frames(scene, file_out, directory, between, frame_start))
            compositor_output(scene, layer, denoise_passes=denoise)  # the scene as a full export leaves it
    finally:
        scene.frame_set(keep)
    objects, classes = _objects_and_classes(scene)
    r = scene.render
    with open(os.path.join(directory, "cameras.json"), "w") as fh:
        json.dump({"convention": "opengl_cam_to_world", "frames": frames}, fh, indent=1)
    extra = {"generator": generator, "renderer": "Cycles (Blender %s)" % bpy.app.version_string, "samples": int(scene.cycles.samples),
             "denoise": bool(denoise), "denoiser_available": has_denoiser, "blender_frames": [frame_start, frame_end], "materials_wired": wired,
             "material_class": classes, "blend_file": os.path.basename(bpy.data.filepath),
             "frame_seconds": {"keyframe": _mean(cost, key_frames, 0), "keyframe_cpu": _mean(cost, key_frames, 1),
                               "gbuffer": _mean(cost, between, 0), "gbuffer_cpu": _mean(cost, between, 1),
                               "per_frame": [round(cost[t][0], 4) for t in range(n)]}}
    if not has_denoiser:
        extra["note"] = NO_DENOISER
    if keys is not None:
        extra.update(gbuffer_samples=int(gbuffer_samples), gbuffer_passes=list(GBUFFER_PASSES) + ["basecolor", "roughness", "metallic"])
    shot = {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "num_frames": n,
        "width": int(r.resolution_x * r.resolution_percentage / 100), "height": int(r.resolution_y * r.resolution_percentage / 100),
        "fps": float(r.fps) / float(r.fps_base), "caption": caption, "objects": objects, "irradiance_normalized": False,
    }
    if keys is not None:
        shot["keyframes"] = list(keys)
    shot["extra"] = extra
    with open(os.path.join(directory, "shot.json"), "w") as fh:
        json.dump(shot, fh, indent=1)
    return n
