"""The render set-up: passes and shader AOVs on the view layer, AOV outputs in every material, the File Output node.

A copy of ``x2video.cycles.passes`` (the source of truth; the add-on cannot import x2video). X2Video's
``tests/test_blender_addon.py`` checks that the constants are equal and that the shared functions
(``configure_view_layer``, ``wire_material`` and its helpers) are the same code, statement by statement.
"""

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
#: the tag an AOV output node carries so that re-running `wire_material` replaces, not duplicates
_TAG = "x2video_aov"


def _input(node, *names):
    """The first input of `names` the node has: Blender 4.0 renamed several Principled BSDF inputs
    ("Emission" -> "Emission Color", "Transmission" -> "Transmission Weight", "Specular" -> "Specular IOR Level")."""
    for n in names:
        sock = node.inputs.get(n)
        if sock is not None:
            return sock
    return None


def configure_view_layer(scene, view_layer=None):
    """Our passes and AOVs on `view_layer` (default: the scene's first), multi-layer half EXR output, motion blur off."""
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


def _principled_nodes(tree):
    return [n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"]


def _aov_name(node):
    """The AOV an AOV output node writes to: `aov_name` from Blender 4.2, the node's `name` property before."""
    return node.aov_name if hasattr(node, "aov_name") else node.name


def _aov_outputs(tree):
    """The AOV output nodes of `tree` that write one of our AOVs (ours from an earlier run, or the material's own)."""
    names = {name for name, _, _ in AOVS}
    return [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputAOV" and (n.get(_TAG) or _aov_name(n) in names)]


def wire_material(mat):
    """AOV outputs copying the first Principled BSDF's base colour, roughness, metallic (whatever feeds them).

    AOV outputs the material already has under those names are replaced: Cycles sums the outputs of one AOV,
    so a second one would double the value. Returns the number of AOV nodes written."""
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


def denoiser_available():
    """Whether this Blender's Cycles has OpenImageDenoise (Debian's Blender 3.4 is built without it, and a render
    with denoising on then stops with "Build without OpenImageDenoiser")."""
    try:
        import _cycles
    except ImportError:
        return False
    return bool(getattr(_cycles, "with_openimagedenoise", False))


def compositor_output(scene, layer, denoise_passes=True, passes=FILE_PASSES):
    """A File Output node writing one multi-layer half EXR per frame: `passes` (Combined written as such) and the
    AOVs; with `denoise_passes` the light passes denoised (OpenImageDenoise) and the sampled diffuse ones kept as
    Noisy<Pass>. Replaces the scene's compositor nodes. Set its `base_path` before each render."""
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

    for name in list(passes) + [a for a, _, _ in AOVS]:
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
