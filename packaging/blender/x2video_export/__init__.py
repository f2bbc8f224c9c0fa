"""X2Video shot export: a Blender add-on that renders the current scene into an X2Video shot.

One operator (Properties > Output > X2Video shot, or F3 "Export X2Video Shot") turns on the render
passes and shader AOVs X2Video reads (base colour, roughness and metallic wired from every
Principled BSDF, metals included), renders the frame range with Cycles through a File Output node
into one multi-layer half EXR per frame (``frame_0000.exr``, ...), and writes ``cameras.json``
(the camera's ``matrix_world`` and vertical field of view per frame) and ``shot.json``. Open the
folder in X2Video Studio, or check it with ``x2video info FOLDER``. A keyframe shot (keyframe every N
frames, or a list) renders the full frame on its keyframes only and G-buffer passes between them.

Self-contained: it cannot import x2video. Its set-up (``passes.py``) is a copy of
``x2video.cycles.passes`` (the source of truth); X2Video's test suite checks that they are the same code.
Blender 3.4 to 4.2. Files: ``passes.py`` (the set-up), ``keyframes.py`` (G-buffer frames, timed animation
renders), ``export.py`` (``export_shot``), this file (the operator and the panel).
"""

import bpy
from bpy.props import BoolProperty, IntProperty, PointerProperty, StringProperty

from .export import export_shot
from .keyframes import GBUFFER_SAMPLES

# Blender's add-on list reads `bl_info` from the source with ast (addon_utils), wherever it stands at module level.
bl_info = {
    "name": "X2Video shot export",
    "author": "X2Video Studio",
    "version": (1, 1, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Output > X2Video shot",
    "description": "Render passes + shader AOVs into an X2Video shot (multi-layer EXR frames, cameras.json, shot.json)",
    "category": "Render",
}
GENERATOR = "x2video_export add-on %d.%d.%d" % bl_info["version"]


# ------------------------------------------------------------------------------------------------ UI
class X2VideoExportSettings(bpy.types.PropertyGroup):
    directory: StringProperty(name="Output folder", subtype="DIR_PATH", default="//x2video_shot/")
    use_scene_range: BoolProperty(name="Scene frame range", default=True)
    frame_start: IntProperty(name="Start", default=1)
    frame_end: IntProperty(name="End", default=2)
    denoise: BoolProperty(name="Denoise light passes", default=True,
                          description="OpenImageDenoise on the light passes (the sampled diffuse ones are kept as Noisy<Pass>)")
    caption: StringProperty(name="Caption", default="")
    keyframe_every: IntProperty(name="Keyframe every", default=0, min=0,
                                description="0: every frame a full render; N: a full render on frames 0, N, 2N, ... and the last,"
                                            " G-buffer passes only on the frames between")
    keyframes: StringProperty(name="Keyframes", default="", description="instead of every N: the keyframes, e.g. '0, 8, 16' (from 0)")
    gbuffer_samples: IntProperty(name="G-buffer samples", default=GBUFFER_SAMPLES, min=1,
                                 description="samples of a G-buffer frame (no bounces, no denoiser)")


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
    keyframe_every: IntProperty(name="Keyframe every", default=0, min=0,
                                description="0: every frame a full render; N: a full render on frames 0, N, 2N, ... and the last,"
                                            " G-buffer passes only on the frames between")
    keyframes: StringProperty(name="Keyframes", default="", description="instead of every N: the keyframes, e.g. '0, 8, 16' (from 0)")
    gbuffer_samples: IntProperty(name="G-buffer samples", default=GBUFFER_SAMPLES, min=1,
                                 description="samples of a G-buffer frame (no bounces, no denoiser)")

    def execute(self, context):
        scene = context.scene
        settings = scene.x2video_export
        directory = bpy.path.abspath(self.directory or settings.directory)
        start = self.frame_start if self.frame_start >= 0 else scene.frame_start
        end = self.frame_end if self.frame_end >= 0 else scene.frame_end
        try:
            n = export_shot(scene, directory, start, end, denoise=self.denoise, caption=self.caption or settings.caption,
                            ids=self.assign_ids, report=lambda m: self.report({"INFO"}, m), keyframe_every=self.keyframe_every,
                            keyframes=self.keyframes, gbuffer_samples=self.gbuffer_samples, generator=GENERATOR)
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
        col.prop(s, "keyframe_every")
        col.prop(s, "keyframes")
        col.prop(s, "gbuffer_samples")
        op = col.operator(X2VIDEO_OT_export_shot.bl_idname, icon="RENDER_ANIMATION")
        op.directory, op.denoise, op.caption = s.directory, s.denoise, s.caption
        op.keyframe_every, op.keyframes, op.gbuffer_samples = s.keyframe_every, s.keyframes, s.gbuffer_samples
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
