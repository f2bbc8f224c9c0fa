"""Look-dev changes made in Blender for `bench.edits_data`: the edit a person would make in x2video, made in the scene
itself so that Cycles renders its truth. Imported only in the Cycles child process (needs `bpy`).

A look is a plain dict (what bench.edits_data writes to edits.json beside x2video's `Edits`):

- ``{"kind": "albedo", "id": ID, "color": [r, g, b]}``: every material of object ID gets Base Color := color (linear);
- ``{"kind": "rough" | "gloss", "id": ID, "value": v}``: Roughness := v;
- ``{"kind": "metal_off" | "metal_on", "id": ID, "value": 0 | 1}``: Metallic := v;
- ``{"kind": "light", "scale": s, "tint": [r, g, b]}``: every lamp, emitter and the world times s, their colours
  times the tint.

The object's materials are copied first (another object sharing one keeps its look), and a texture feeding an input
that is overwritten is unlinked. `apply_look` runs after `build_room` and before `wire_all_materials`, so the AOVs
(basecolor, roughness, metallic) the after-render writes hold the new values.
"""
from __future__ import annotations

from typing import Any

import bpy

from x2video.cycles.classes import classify
from x2video.cycles.shot import scale_lights

#: the Principled BSDF input each object look sets
INPUT = {"albedo": "Base Color", "rough": "Roughness", "gloss": "Roughness", "metal_off": "Metallic", "metal_on": "Metallic"}


def _principled(mat: "bpy.types.Material") -> Any:
    if not mat.use_nodes or mat.node_tree is None:
        return None
    return next((n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)


def own_materials(oid: int) -> list["bpy.types.Material"]:
    """The materials of every mesh object whose pass index is `oid`, each replaced by a copy of its own (one copy per
    material, so that no other object changes). ValueError when no object carries that id."""
    obs = [ob for ob in bpy.data.objects if ob.type == "MESH" and ob.pass_index == oid]
    if not obs:
        raise ValueError(f"look: no mesh object has pass index {oid}")
    copies: dict[str, bpy.types.Material] = {}
    for ob in obs:
        for slot in ob.material_slots:  # the procedural rooms give every object a mesh of its own: a slot's material is its own
            if slot.material is None:
                continue
            name = slot.material.name
            if name not in copies:
                copies[name] = slot.material.copy()
                copies[name].name = f"{name}_edit{oid}"
            slot.material = copies[name]
    return list(copies.values())


def _set(mat: "bpy.types.Material", socket_name: str, value: Any) -> bool:
    """Set the first Principled BSDF's input `socket_name` to `value`, unlinking what fed it; False without one."""
    bsdf = _principled(mat)
    if bsdf is None:
        return False
    sock = bsdf.inputs[socket_name]
    for link in list(sock.links):
        mat.node_tree.links.remove(link)
    sock.default_value = (*value, 1.0) if socket_name == "Base Color" else float(value)
    return True


def _tint_socket(tree: "bpy.types.NodeTree", sock: Any, tint: tuple[float, float, float]) -> None:
    """Multiply a colour input by `tint`: its value when unlinked, else through a vector-multiply node on its link."""
    if not sock.is_linked:
        v = sock.default_value
        sock.default_value = (v[0] * tint[0], v[1] * tint[1], v[2] * tint[2], v[3])
        return
    src = sock.links[0].from_socket
    mul = tree.nodes.new("ShaderNodeVectorMath")
    mul.operation = "MULTIPLY"
    mul.inputs[1].default_value = tuple(tint)
    tree.links.new(src, mul.inputs[0])
    tree.links.new(mul.outputs[0], sock)


def light_look(scale: float, tint: tuple[float, float, float]) -> int:
    """Every lamp, emitter and the world times `scale`, their colours times `tint`; returns how many were tinted."""
    scale_lights(scale)
    n = 0
    for light in bpy.data.lights:
        if not light.cycles.is_portal:
            light.color = tuple(c * t for c, t in zip(light.color, tint))
            n += 1
    for mat in bpy.data.materials:
        if not mat.use_nodes:
            continue
        for node in list(mat.node_tree.nodes):
            if node.bl_idname == "ShaderNodeBsdfPrincipled":
                sock = node.inputs.get("Emission Color") or node.inputs.get("Emission")
                strength = node.inputs.get("Emission Strength")
                if sock is not None and strength is not None and strength.default_value > 0:
                    _tint_socket(mat.node_tree, sock, tint)
                    n += 1
            elif node.bl_idname == "ShaderNodeEmission":
                _tint_socket(mat.node_tree, node.inputs["Color"], tint)
                n += 1
    world = bpy.context.scene.world
    if world is not None and world.use_nodes:
        for node in list(world.node_tree.nodes):
            if node.bl_idname == "ShaderNodeBackground":
                _tint_socket(world.node_tree, node.inputs["Color"], tint)
                n += 1
    return n


def apply_look(look: dict, built: dict) -> dict:
    """Make `look` in the built scene (`build_room`'s result, whose material class of the object is updated); returns
    what was changed, for shot.json."""
    kind = look["kind"]
    if kind == "light":
        tint = tuple(float(v) for v in look.get("tint", (1.0, 1.0, 1.0)))
        return {**look, "tinted": light_look(float(look.get("scale", 1.0)), tint)}  # type: ignore[arg-type]
    if kind not in INPUT:
        raise ValueError(f"look: unknown kind {kind!r} (one of light, {', '.join(INPUT)})")
    oid = int(look["id"])
    value = look["color"] if kind == "albedo" else look["value"]
    mats = [m.name for m in own_materials(oid) if _set(m, INPUT[kind], value)]
    if not mats:
        raise ValueError(f"look {kind}: object {oid} has no Principled BSDF material")
    classes = built.get("material_class", {})
    if kind != "albedo" and classes.get(oid) in ("diffuse", "glossy", "metal"):
        mat = bpy.data.materials[mats[0]]
        bsdf = _principled(mat)
        classes[oid] = classify(roughness=float(bsdf.inputs["Roughness"].default_value), metallic=float(bsdf.inputs["Metallic"].default_value))
    return {**look, "materials": mats}
