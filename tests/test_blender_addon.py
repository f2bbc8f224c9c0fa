"""The Blender add-on (packaging/blender/x2video_export.py): its copy of the pass/AOV set-up equals
x2video.cycles.passes (read with ast, no bpy), and run headless it writes a shot `x2video info` reads."""
import ast
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ADDON = ROOT / "packaging" / "blender" / "x2video_export.py"
PASSES = ROOT / "core" / "x2video" / "cycles" / "passes.py"
CLASSES = ROOT / "core" / "x2video" / "cycles" / "classes.py"
SHARED = ("AOVS", "PASS_FLAGS", "LIGHT_PASSES", "FILE_PASSES", "_TAG")

bpy_missing = subprocess.run([sys.executable, "-c", "import importlib.util,sys; sys.exit(importlib.util.find_spec('bpy') is None)"], check=False).returncode


def module_constants(path: Path) -> dict:
    """Top-level NAME = <literal, or literals and earlier names joined by +> of a module, without importing it."""
    found: dict = {}

    def value(node):
        if isinstance(node, ast.Name):
            return found[node.id]
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
            return value(node.left) + value(node.right)
        return ast.literal_eval(node)

    for stmt in ast.parse(path.read_text()).body:
        target = stmt.targets[0] if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 else getattr(stmt, "target", None)
        if isinstance(target, ast.Name) and getattr(stmt, "value", None) is not None:
            try:
                found[target.id] = value(stmt.value)
            except (ValueError, KeyError, TypeError):
                pass
    return found


def test_addon_setup_equals_passes_py():
    addon, passes = module_constants(ADDON), module_constants(PASSES)
    for name in SHARED:
        assert name in passes, f"passes.py lost {name}"
        assert addon.get(name) == passes[name], f"{name}: the add-on's copy differs from x2video.cycles.passes"
    assert addon["KEEP_NOISY"] == ("DiffDir", "DiffInd")  # compositor_output's default keep_noisy
    assert addon["GLOSSY_BELOW"] == module_constants(CLASSES)["GLOSSY_BELOW"]
    info = addon["bl_info"]
    assert info["blender"] == (3, 4, 0) and info["category"] == "Render"
    tree = ast.parse(ADDON.read_text())
    names = {n.name for n in tree.body if isinstance(n, (ast.ClassDef, ast.FunctionDef))}
    assert {"X2VIDEO_OT_export_shot", "X2VIDEO_PT_export", "register", "unregister"} <= names
    imported = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))
                for a in (n.names if isinstance(n, ast.Import) else [ast.alias(n.module or "")])}
    assert "x2video" not in imported, "the add-on must be self-contained"



def function_bodies(path: Path, rename: dict[str, str] | None = None) -> dict[str, str]:
    """Top-level function name -> its body without the docstring (ast.dump; names in `rename` renamed), no import."""
    out = {}
    for fn in ast.parse(path.read_text()).body:
        if not isinstance(fn, ast.FunctionDef):
            continue
        body = fn.body[1:] if isinstance(fn.body[0], ast.Expr) and isinstance(fn.body[0].value, ast.Constant) else fn.body
        module = ast.Module(body=body, type_ignores=[])
        for node in ast.walk(module):
            if isinstance(node, ast.Name) and node.id in (rename or {}):
                node.id = rename[node.id]
        out[rename.get(fn.name, fn.name) if rename else fn.name] = ast.dump(module)
    return out


def test_addon_wires_materials_as_passes_py_does():
    """The add-on's material wiring (the AOVs' sources) is x2video.cycles.passes' to the statement; only the helper's name
    and the docstrings differ. (Its view layer and compositor set-up differ on purpose: older Blenders' Cycles pass
    flags, OpenImageDenoise's ACCURATE prefilter for a user's shot; their pass table is the one compared above.)"""
    addon, passes = function_bodies(ADDON, {"_principled": "_principled_nodes"}), function_bodies(PASSES)
    for name in ("wire_material", "_principled_nodes"):
        assert addon[name] == passes[name], f"{name}: the add-on's copy differs from x2video.cycles.passes"

SCENE = textwrap.dedent("""
    import importlib.util, math, os, sys
    devnull = os.open(os.devnull, os.O_WRONLY); os.dup2(devnull, 1)  # Blender's progress lines
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    spec = importlib.util.spec_from_file_location("x2video_export", sys.argv[1])
    addon = importlib.util.module_from_spec(spec); spec.loader.exec_module(addon); addon.register()
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples, scene.cycles.device = 4, "CPU"
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 48, 32, 100
    scene.render.threads_mode, scene.render.threads = "FIXED", 1

    def obj(name, mesh_op, mat_args, **kw):
        mesh_op(**kw)
        ob = bpy.context.active_object; ob.name = name
        mat = bpy.data.materials.new(name); mat.use_nodes = True
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        for k, v in mat_args.items():
            bsdf.inputs[k].default_value = v
        ob.data.materials.append(mat)
        return ob

    obj("floor", bpy.ops.mesh.primitive_plane_add, {"Base Color": (0.6, 0.5, 0.4, 1), "Roughness": 0.6}, size=8)
    obj("cube", bpy.ops.mesh.primitive_cube_add, {"Base Color": (0.9, 0.7, 0.4, 1), "Metallic": 1.0, "Roughness": 0.2},
        size=1, location=(0, 0, 0.5))
    light = bpy.data.objects.new("light", bpy.data.lights.new("light", "AREA"))
    light.data.energy, light.data.size, light.location = 300, 2, (1, -1, 3)
    scene.collection.objects.link(light)
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam); scene.camera = cam
    for f, x in ((1, 0.0), (2, 0.4)):
        cam.location, cam.rotation_euler = (x, -4, 2), (math.radians(65), 0, 0)
        cam.keyframe_insert("location", frame=f); cam.keyframe_insert("rotation_euler", frame=f)
    scene.frame_start, scene.frame_end = 1, 2
    res = bpy.ops.x2video.export_shot(directory=sys.argv[2], frame_start=1, frame_end=2, caption="a brass cube on a floor")
    assert res == {"FINISHED"}, res
    addon.unregister()
""")


@pytest.mark.slow
@pytest.mark.skipif(bool(bpy_missing), reason="bpy is not installed: `pip install -e '.[cycles]'` (scripts/setup.sh does)")
def test_addon_exports_a_shot_x2video_reads(tmp_path):
    import numpy as np

    from x2video.io import load_shot

    out = tmp_path / "shot"
    script = tmp_path / "scene.py"
    script.write_text(SCENE)
    proc = subprocess.run([sys.executable, str(script), str(ADDON), str(out)], capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert sorted(p.name for p in out.iterdir()) == ["cameras.json", "frame_0000.exr", "frame_0001.exr", "shot.json"]
    info = subprocess.run([sys.executable, "-m", "x2video", "info", str(out), "--json"], capture_output=True, text=True, timeout=120, check=False,
                          env={**os.environ, "QT_QPA_PLATFORM": "offscreen"})
    assert info.returncode == 0, info.stderr[-3000:]
    report = json.loads(info.stdout)
    assert report["frames"] == 2 and (report["width"], report["height"]) == (48, 32)
    assert {"albedo", "normal", "roughness", "metallic", "irradiance"} <= set(report["channels"]) and not report["dropped"]
    assert report["poses"] and report["caption"] == "a brass cube on a floor"
    shot = load_shot(out)
    cams = json.loads((out / "cameras.json").read_text())["frames"]
    assert np.allclose(np.asarray(cams[1]["cam_to_world"])[:3, 3], (0.4, -4, 2))  # matrix_world of frame 2
    assert cams[0]["fov_y_deg"] == pytest.approx(2 * np.degrees(np.arctan(36 / 2 / 50 / 1.5)), abs=1e-3)  # 50 mm, 36 mm sensor, 3:2
    fr = shot.frame(0)
    ids = fr["ids"][..., 0]
    meta = json.loads((out / "shot.json").read_text())
    cube = int(next(k for k, v in meta["objects"].items() if v == "cube"))
    assert meta["extra"]["material_class"][str(cube)] == "metal"
    on_cube = ids == cube
    assert on_cube.any()
    # the metal's base colour reaches the basecolor AOV (DiffCol is black on metals), metallic is 1 there
    assert np.median(fr["metallic"][on_cube]) == pytest.approx(1.0, abs=0.01)
    assert np.allclose(np.median(fr["albedo"][on_cube], axis=0), (0.9, 0.7, 0.4), atol=0.02)
