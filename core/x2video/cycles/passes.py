"""Set up a Blender scene so that its render holds our five channels: render passes plus shader AOVs, written as multi-layer EXR.

What our Blender loader (`x2video.io.multilayer`) reads, and what this module turns on:

- ``DiffCol``, ``DiffDir``, ``DiffInd``: irradiance = DiffDir + DiffInd (Cycles divides the diffuse
  light passes by the diffuse colour, which is our convention); ``GlossCol/Dir/Ind``, ``Emit``,
  ``TransCol/Dir/Ind``, ``Env`` (the world seen through windows): the rest of Cycles' exact split
  of ``Combined``;
- ``Normal`` (world space; ``cameras.json`` beside the frames turns it into camera space),
  ``IndexOB`` (object ids), ``Depth``, ``Vector`` (motion);
- shader AOVs ``basecolor`` (colour; ``DiffCol`` is black on metals), ``roughness`` and
  ``metallic`` (values), wired from the inputs of every Principled BSDF of every material.

Needs `bpy` (Blender 3.4 or 4.2); imported only in Blender worker processes and the add-on.
"""
from __future__ import annotations

import bpy


def set_input(node, names: tuple[str, ...], value) -> None:
    """Set the first input of `names` this Blender has (4.x renamed Emission, Transmission, Specular)."""
    for n in names:
        sock = node.inputs.get(n)
        if sock is not None:
            sock.default_value = value
            return
    raise KeyError(f"{node.name}: none of the inputs {names}")


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
#: the tag an AOV output node carries so that re-running `wire_material` replaces, not duplicates
_TAG = "x2video_aov"


def configure_view_layer(scene: "bpy.types.Scene", view_layer: "bpy.types.ViewLayer | None" = None) -> None:
    """Turn on our passes and AOVs on `view_layer` (default: the scene's first) and multi-layer half EXR output."""
    layer = view_layer or scene.view_layers[0]
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
    # Cycles' denoiser treats Combined only; the Vector pass needs motion blur off.
    scene.render.use_motion_blur = False
    s = scene.render.image_settings
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "16"
    s.exr_codec = "ZIP"


def _principled_nodes(tree: "bpy.types.NodeTree") -> list:
    return [n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"]


def _aov_name(node) -> str:
    """The AOV an AOV output node writes to: `aov_name` from Blender 4.2, the node's `name` property before."""
    return node.aov_name if hasattr(node, "aov_name") else node.name


def _aov_outputs(tree: "bpy.types.NodeTree") -> list:
    """The AOV output nodes of `tree` that write one of our AOVs (ours from an earlier run, or the material's own)."""
    names = {name for name, _, _ in AOVS}
    return [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputAOV" and (n.get(_TAG) or _aov_name(n) in names)]


def wire_material(mat: "bpy.types.Material") -> int:
    """Add AOV outputs to `mat` copying its first Principled BSDF's base colour, roughness, metallic.

    Whatever feeds an input (a texture, a constant) feeds its AOV too. AOV outputs the material already
    has under those names are replaced: Cycles sums the outputs of one AOV, so a second would double the
    value. Returns the number of AOV nodes written (0 for materials without a Principled BSDF: their AOVs
    stay 0, as for emitters).
    """
    if not mat.use_nodes or mat.node_tree is None:
        return 0
    tree = mat.node_tree
    for n in _aov_outputs(tree):
        tree.nodes.remove(n)
    bsdfs = _principled_nodes(tree)
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
        else:  # up to 4.1 the AOV name is the node's `name` property (API docs 3.4 to 4.1)
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


def wire_all_materials() -> int:
    """`wire_material` on every material of the file; returns how many materials got AOVs."""
    return sum(1 for m in bpy.data.materials if wire_material(m) > 0)


#: light passes the compositor can denoise (OpenImageDenoise, with Cycles' denoising albedo and normal as guides)
LIGHT_PASSES = ("DiffDir", "DiffInd", "GlossDir", "GlossInd", "TransDir", "TransInd")
#: every render-layer output written to the file, under Blender's own pass names ("Image" is written as "Combined")
FILE_PASSES = ("Image", "DiffCol", "GlossCol", "TransCol", "Emit", "Env", "Normal", "IndexOB", "Depth", "Vector") + LIGHT_PASSES


def compositor_output(scene: "bpy.types.Scene", *, denoise_passes: bool = True,
                      keep_noisy: tuple[str, ...] = ("DiffDir", "DiffInd")) -> "bpy.types.Node":
    """Write the frame through the compositor: one multi-layer half EXR (a File Output node) holding Combined,
    every pass and AOV of `configure_view_layer`, the light passes denoised (as an archviz compositor
    would) and the passes of `keep_noisy` also as sampled under ``Noisy<Pass>`` (for noise augmentation).

    Returns the File Output node; set its ``base_path`` to ``<folder>/<prefix>`` before each render
    (Blender appends the frame number and ``.exr``)."""
    layer = scene.view_layers[0]
    if denoise_passes:
        layer.cycles.denoising_store_passes = True
    scene.use_nodes = True
    tree = scene.node_tree
    for n in list(tree.nodes):
        tree.nodes.remove(n)
    rl = tree.nodes.new("CompositorNodeRLayers")
    comp = tree.nodes.new("CompositorNodeComposite")
    tree.links.new(rl.outputs["Image"], comp.inputs["Image"])
    out = tree.nodes.new("CompositorNodeOutputFile")
    out.format.file_format, out.format.color_depth, out.format.exr_codec = "OPEN_EXR_MULTILAYER", "16", "ZIP"
    out.layer_slots.clear()

    def slot(name: str, socket) -> None:
        out.layer_slots.new(name)
        tree.links.new(socket, out.inputs[name])

    names = list(FILE_PASSES) + [a for a, _, _ in AOVS]
    for name in names:
        sock = rl.outputs.get(name)
        if sock is None or not sock.enabled:
            continue
        label = "Combined" if name == "Image" else name
        if denoise_passes and name in LIGHT_PASSES:
            dn = tree.nodes.new("CompositorNodeDenoise")
            # FAST: Cycles' denoising albedo and normal are clean enough as guides; ACCURATE denoised them again for
            # each of the six passes (0.87 -> 0.48 s of fixed cost per 160x112 frame)
            dn.prefilter = "FAST"
            tree.links.new(sock, dn.inputs["Image"])
            tree.links.new(rl.outputs["Denoising Normal"], dn.inputs["Normal"])
            tree.links.new(rl.outputs["Denoising Albedo"], dn.inputs["Albedo"])
            slot(label, dn.outputs["Image"])
            if name in keep_noisy:
                slot(f"Noisy{name}", sock)
        else:
            slot(label, sock)
    return out
