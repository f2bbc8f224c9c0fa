"""X2Video shot export: a Blender add-on that renders the current scene into an X2Video shot.

One operator (Properties > Output > X2Video shot, or F3 "Export X2Video Shot") turns on the render
passes and shader AOVs X2Video reads (base colour, roughness and metallic wired from every
Principled BSDF, metals included), renders the frame range with Cycles through a File Output node
into one multi-layer half EXR per frame (``frame_0000.exr``, ...), and writes ``cameras.json``
(the camera's ``matrix_world`` and vertical field of view per frame) and ``shot.json``. Open the
folder in X2Video Studio, or check it with ``x2video info FOLDER``.

Self-contained: it cannot import x2video. Its pass and AOV lists are a copy of
``x2video.cycles.passes`` (the source of truth); X2Video's test suite checks that they are equal.
Blender 3.4 to 4.2.
"""

import json
import math
import os
import shutil
import tempfile

import bpy
from bpy.props import BoolProperty, IntProperty, PointerProperty, StringProperty

# Blender's add-on list reads `bl_info` from the source with ast (addon_utils), wherever it stands at module level.
bl_info = {
    "name": "X2Video shot export",
    "author": "X2Video Studio",
    "version": (1, 0, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Output > X2Video shot",
    "description": "Render passes + shader AOVs into an X2Video shot (multi-layer EXR frames, cameras.json, shot.json)",
    "category": "Render",
}

# ------------------------------------------------------------------------------------------------ the set-up
# Copied from x2video.cycles.passes (keep equal: tests/test_blender_addon.py compares them).
#: (AOV name, kind, Principled BSDF input it copies)
AOVS = (("basecolor", "COLOR", "Base Color"), ("roughness", "VALUE", "Roughness"), ("metallic", "VALUE", "Metallic"))
#: view-layer flags of the passes we write (attribute names on `bpy.types.ViewLayer`)
PASS_FLAGS = (
    "use_pass_combined", "use_pass_z", "use_pass_normal", "use_pass_vector", "use_pass_object_index",
    "use_pass_diffuse_direct", "use_pass_diffuse_indirect", "use_pass_diffuse_color",
    "use_pass_glossy_direct", "use_pass_glossy_indirect", "use_pass_glossy_color",
    "use_pass_transmission_direct", "use_pass_transmission_indirect", "use_pass_transmission_color",
    "use_pass_emit", "use_pass_environment",
)
#: light passes the compositor can denoise (OpenImageDenoise, with Cycles' denoising albedo and normal as guides)
LIGHT_PASSES = ("DiffDir", "DiffInd", "GlossDir", "GlossInd", "TransDir", "TransInd")
#: every render-layer output written to the file, under Blender's own pass names ("Image" is written as "Combined")
FILE_PASSES = ("Image", "DiffCol", "GlossCol", "TransCol", "Emit", "Env", "Normal", "IndexOB", "Depth", "Vector") + LIGHT_PASSES
#: the sampled (not denoised) light passes also written, as Noisy<Pass>
KEEP_NOISY = ("DiffDir", "DiffInd")
#: a dielectric below this roughness is "glossy" (x2video.cycles.classes.GLOSSY_BELOW)
GLOSSY_BELOW = 0.25
_TAG = "x2video_aov"
FORMAT_NAME, FORMAT_VERSION = "x2video-shot", 1
GENERATOR = "x2video_export add-on %d.%d.%d" % bl_info["version"]


def _input(node, *names):
    """The first input of `names` the node has: Blender 4.0 renamed several Principled BSDF inputs
    ("Emission" -> "Emission Color", "Transmission" -> "Transmission Weight", "Specular" -> "Specular IOR Level")."""
    for n in names:
        sock = node.inputs.get(n)
        if sock is not None:
            return sock
    return None


def configure_view_layer(scene, layer):
    """Our passes and AOVs on `layer`, multi-layer half EXR output, motion blur off (the Vector pass needs it off)."""
    for flag in PASS_FLAGS:
        if hasattr(layer, flag):
            setattr(layer, flag, True)
        elif hasattr(layer.cycles, flag):  # older Blenders kept some Cycles passes on the Cycles settings
            setattr(layer.cycles, flag, True)
    have = {a.name for a in layer.aovs}
    for name, kind, _ in AOVS:
        if name not in have:
            aov = layer.aovs.add()
            aov.name, aov.type = name, kind
    scene.render.use_motion_blur = False
    s = scene.render.image_settings
    s.file_format, s.color_depth, s.exr_codec = "OPEN_EXR_MULTILAYER", "16", "ZIP"


def _principled(tree):
    return [n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"]


def wire_material(mat):
    """AOV outputs copying the first Principled BSDF's base colour, roughness, metallic (whatever feeds them)."""
    if not mat.use_nodes or mat.node_tree is None:
        return 0
    tree = mat.node_tree
    for n in [n for n in tree.nodes if n.get(_TAG)]:
        tree.nodes.remove(n)
    bsdfs = _principled(tree)
    if not bsdfs:
        return 0
    bsdf = bsdfs[0]
    written = 0
    for name, kind, socket_name in AOVS:
        socket = bsdf.inputs.get(socket_name)
        if socket is None:
            continue
        out = tree.nodes.new("ShaderNodeOutputAOV")
        out[_TAG] = True
        out.location = (bsdf.location.x + 300, bsdf.location.y - 120 * (written + 1))
        if hasattr(out, "aov_name"):  # Blender 4.2+
            out.aov_name = name
        else:  # up to 4.1 the AOV name is the node's `name` property
            out.name = name
        target = out.inputs["Color" if kind == "COLOR" else "Value"]
        if socket.is_linked:
            tree.links.new(socket.links[0].from_socket, target)
        elif kind == "COLOR":
            target.default_value = tuple(socket.default_value)
        else:
            target.default_value = float(socket.default_value)
        written += 1
    return written


def compositor_output(scene, layer, denoise_passes=True):
    """A File Output node writing one multi-layer half EXR per frame: Combined, every pass, the AOVs; the light
    passes denoised (OpenImageDenoise) with the sampled diffuse ones kept as Noisy<Pass>. Replaces the scene's
    compositor nodes."""
    if denoise_passes:
        layer.cycles.denoising_store_passes = True
    scene.use_nodes = True
    tree = scene.node_tree
    for n in list(tree.nodes):
        tree.nodes.remove(n)
    rl = tree.nodes.new("CompositorNodeRLayers")
    rl.layer = layer.name
    comp = tree.nodes.new("CompositorNodeComposite")
    tree.links.new(rl.outputs["Image"], comp.inputs["Image"])
    out = tree.nodes.new("CompositorNodeOutputFile")
    out.format.file_format, out.format.color_depth, out.format.exr_codec = "OPEN_EXR_MULTILAYER", "16", "ZIP"
    out.layer_slots.clear()

    def slot(name, socket):
        out.layer_slots.new(name)
        tree.links.new(socket, out.inputs[name])

    for name in list(FILE_PASSES) + [a for a, _, _ in AOVS]:
        sock = rl.outputs.get(name)
        if sock is None or not sock.enabled:
            continue
        label = "Combined" if name == "Image" else name
        if denoise_passes and name in LIGHT_PASSES:
            dn = tree.nodes.new("CompositorNodeDenoise")
            if hasattr(dn, "prefilter"):
                dn.prefilter = "ACCURATE"
            tree.links.new(sock, dn.inputs["Image"])
            tree.links.new(rl.outputs["Denoising Normal"], dn.inputs["Normal"])
            tree.links.new(rl.outputs["Denoising Albedo"], dn.inputs["Albedo"])
            slot(label, dn.outputs["Image"])
            if name in KEEP_NOISY:
                slot("Noisy" + name, sock)
        else:
            slot(label, sock)
    return out


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
    bsdfs = _principled(mat.node_tree)
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


# ------------------------------------------------------------------------------------------------ the export
def export_shot(scene, directory, frame_start, frame_end, denoise=True, caption="", ids=True, report=print):
    """Render frames frame_start..frame_end of `scene` into the shot folder `directory`; returns the frame count."""
    if scene.camera is None:
        raise ValueError("the scene has no camera")
    if frame_end < frame_start:
        raise ValueError("frame range %d..%d is empty" % (frame_start, frame_end))
    os.makedirs(directory, exist_ok=True)
    if scene.render.engine != "CYCLES":
        report("switching the render engine to Cycles (the light passes are Cycles')")
        scene.render.engine = "CYCLES"
    layer = bpy.context.view_layer if bpy.context.view_layer.name in scene.view_layers else scene.view_layers[0]
    configure_view_layer(scene, layer)
    wired = sum(1 for m in bpy.data.materials if wire_material(m) > 0)
    if ids:
        assign_ids(scene)
    file_out = compositor_output(scene, layer, denoise_passes=denoise)
    frames, n = [], frame_end - frame_start + 1
    keep = scene.frame_current
    try:
        for t, f in enumerate(range(frame_start, frame_end + 1)):
            scene.frame_set(f)
            frames.append({"frame": t, "cam_to_world": cam_to_world(scene.camera), "fov_y_deg": fov_y_deg(scene, scene.camera)})
            tmp = tempfile.mkdtemp(prefix=".tmp_", dir=directory)
            try:
                file_out.base_path = os.path.join(tmp, "frame_")
                bpy.ops.render.render(write_still=False)
                os.replace(os.path.join(tmp, "frame_%04d.exr" % f), os.path.join(directory, "frame_%04d.exr" % t))
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
    finally:
        scene.frame_set(keep)
    objects, classes = {}, {}
    for ob in scene.objects:
        if ob.pass_index > 0 and ob.type in ("MESH", "CURVE", "SURFACE", "META", "FONT"):
            key = str(ob.pass_index)
            objects[key] = objects[key] + ", " + ob.name if key in objects else ob.name
            mats = [s.material for s in ob.material_slots if s.material is not None]
            cls = [c for c in (classify(m) for m in mats) if c is not None]
            if cls and key not in classes:
                classes[key] = "emitter" if "emitter" in cls else cls[0]
    r = scene.render
    with open(os.path.join(directory, "cameras.json"), "w") as fh:
        json.dump({"convention": "opengl_cam_to_world", "frames": frames}, fh, indent=1)
    shot = {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "num_frames": n,
        "width": int(r.resolution_x * r.resolution_percentage / 100), "height": int(r.resolution_y * r.resolution_percentage / 100),
        "fps": float(r.fps) / float(r.fps_base), "caption": caption, "objects": objects, "irradiance_normalized": False,
        "extra": {"generator": GENERATOR, "renderer": "Cycles (Blender %s)" % bpy.app.version_string, "samples": int(scene.cycles.samples),
                  "denoise": bool(denoise), "blender_frames": [frame_start, frame_end], "materials_wired": wired,
                  "material_class": classes, "blend_file": os.path.basename(bpy.data.filepath)},
    }
    with open(os.path.join(directory, "shot.json"), "w") as fh:
        json.dump(shot, fh, indent=1)
    return n


# ------------------------------------------------------------------------------------------------ UI
class X2VideoExportSettings(bpy.types.PropertyGroup):
    directory: StringProperty(name="Output folder", subtype="DIR_PATH", default="//x2video_shot/")
    use_scene_range: BoolProperty(name="Scene frame range", default=True)
    frame_start: IntProperty(name="Start", default=1)
    frame_end: IntProperty(name="End", default=2)
    denoise: BoolProperty(name="Denoise light passes", default=True,
                          description="OpenImageDenoise on the light passes (the sampled diffuse ones are kept as Noisy<Pass>)")
    caption: StringProperty(name="Caption", default="")


class X2VIDEO_OT_export_shot(bpy.types.Operator):
    """Set up passes and AOVs, render the frame range into multi-layer EXR frames, write cameras.json and shot.json"""

    bl_idname = "x2video.export_shot"
    bl_label = "Export X2Video Shot"
    bl_options = {"REGISTER"}

    directory: StringProperty(name="Output folder", subtype="DIR_PATH", default="")
    frame_start: IntProperty(name="Start", default=-1, description="first frame (-1: the scene's)")
    frame_end: IntProperty(name="End", default=-1, description="last frame (-1: the scene's)")
    denoise: BoolProperty(name="Denoise light passes", default=True)
    caption: StringProperty(name="Caption", default="")
    assign_ids: BoolProperty(name="Assign object ids", default=True, description="give objects with pass index 0 a free one")

    def execute(self, context):
        scene = context.scene
        settings = scene.x2video_export
        directory = bpy.path.abspath(self.directory or settings.directory)
        start = self.frame_start if self.frame_start >= 0 else scene.frame_start
        end = self.frame_end if self.frame_end >= 0 else scene.frame_end
        try:
            n = export_shot(scene, directory, start, end, denoise=self.denoise, caption=self.caption or settings.caption,
                            ids=self.assign_ids, report=lambda m: self.report({"INFO"}, m))
        except (ValueError, RuntimeError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, "X2Video shot: %d frame(s) in %s" % (n, directory))
        return {"FINISHED"}


class X2VIDEO_PT_export(bpy.types.Panel):
    bl_label = "X2Video shot"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "output"

    def draw(self, context):
        s = context.scene.x2video_export
        col = self.layout.column()
        col.prop(s, "directory")
        col.prop(s, "caption")
        col.prop(s, "use_scene_range")
        row = col.row(align=True)
        row.enabled = not s.use_scene_range
        row.prop(s, "frame_start")
        row.prop(s, "frame_end")
        col.prop(s, "denoise")
        op = col.operator(X2VIDEO_OT_export_shot.bl_idname, icon="RENDER_ANIMATION")
        op.directory, op.denoise, op.caption = s.directory, s.denoise, s.caption
        op.frame_start, op.frame_end = (-1, -1) if s.use_scene_range else (s.frame_start, s.frame_end)


_CLASSES = (X2VideoExportSettings, X2VIDEO_OT_export_shot, X2VIDEO_PT_export)


def register():
    for cls in _CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.x2video_export = PointerProperty(type=X2VideoExportSettings)


def unregister():
    del bpy.types.Scene.x2video_export
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)


if __name__ == "__main__":
    register()
