"""Material classes per object id, for a per-material breakdown of a metric (diffuse / glossy / metal / glass / emitter).

A Cycles shot's ``ids`` channel (``IndexOB``) holds each object's ``pass_index``; this module says
which material class each id stands for, from the shot's shot.json alone (no bpy):

- the outside scenes (`x2video.cycles.outside`) write the map themselves: ``extra.material_class``;
- procedural Cycles rooms from generator ``x2video.cycles v2`` on write the map too; v1 rooms are rebuilt from ``extra.room_seed``
  (the scene description is pure numpy) with ``extra.path_traced`` (metal objects, glossy floor,
  mirror) applied as `x2video.cycles.room` applies it.

An object is classed by its main material (its first part's), except that an object with any
emissive part is an ``emitter``. Id 0 (the background, and the procedural rooms' window panes)
is never in the map.
"""
from __future__ import annotations

from typing import Any

CLASSES = ("diffuse", "glossy", "metal", "glass", "emitter")
#: a dielectric below this roughness is "glossy"
GLOSSY_BELOW = 0.25


def classify(*, roughness: float, metallic: float = 0.0, transmission: float = 0.0, emission: float = 0.0) -> str:
    """The class of one Principled-style material (emission: its strength times its colour's maximum)."""
    if emission > 0:
        return "emitter"
    if metallic >= 0.5:
        return "metal"
    if transmission >= 0.5:
        return "glass"
    return "glossy" if roughness < GLOSSY_BELOW else "diffuse"


def object_class(scene: Any, obj: Any, *, metal: set[int] | frozenset[int] = frozenset(), glossy_floor: float | None = None,
                 glass: set[int] | frozenset[int] = frozenset(), lacquer: dict[int, float] | None = None) -> str:
    """The class of procedural object `obj` of `scene` as `x2video.cycles.room.build_room` builds it: `metal` / `glass`
    object ids, the glossy floor's roughness, `lacquer` {id: roughness}. The one rule for rooms built (room.py, v2)
    and rooms read back from their shot.json (`_room_classes`, v1)."""
    import numpy as np

    if obj.category == "mirror":
        return "metal"
    parts = [p for p in obj.parts if not scene.materials[p.material].sky]
    if any(float(np.max(scene.materials[p.material].emission)) > 0 for p in parts):
        return "emitter"
    if obj.id in metal:
        return "metal"
    if obj.id in glass:
        return "glass"
    if lacquer and obj.id in lacquer:
        return classify(roughness=lacquer[obj.id])
    if obj.category == "floor" and glossy_floor is not None:
        return classify(roughness=float(glossy_floor))
    main = scene.materials[parts[0].material]
    return classify(roughness=float(main.roughness), metallic=float(main.metallic))


def _room_classes(extra: dict[str, Any]) -> dict[int, str]:
    from x2video.procedural.scene import generate_scene

    scene = generate_scene(int(extra["room_seed"]))
    traced = extra.get("path_traced", {}) or {}
    kw = {"metal": {int(i) for i, _ in traced.get("metal", [])}, "glossy_floor": traced.get("glossy_floor")}
    out = {obj.id: object_class(scene, obj, **kw) for obj in scene.objects
           if any(not scene.materials[p.material].sky for p in obj.parts)}
    if traced.get("mirror"):
        out[max(o.id for o in scene.objects) + 1] = "metal"  # room.mirror_object's id
    return out


def material_classes(shot_json: dict[str, Any]) -> dict[int, str]:
    """{object id: class} of a Cycles shot from its parsed shot.json; ValueError when the shot says nothing to go by."""
    extra = shot_json.get("extra", {}) or {}
    if "material_class" in extra:
        out = {int(k): str(v) for k, v in extra["material_class"].items()}
        bad = sorted({v for v in out.values() if v not in CLASSES})
        if bad:
            raise ValueError(f"shot.json: unknown material class(es) {bad}; expected {CLASSES}")
        return out
    if str(extra.get("generator", "")).startswith("x2video.cycles v") and "room_seed" in extra:
        return _room_classes(extra)
    raise ValueError("shot.json: no extra.material_class and not a procedural Cycles room (extra.room_seed); cannot class its objects")
