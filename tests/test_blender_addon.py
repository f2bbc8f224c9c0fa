"""The Blender add-on (packaging/blender/x2video_export/): its set-up is x2video.cycles.passes' code (read with ast,
no bpy), and run headless (the `bpy` module, and Blender itself where a `blender` is on PATH) it writes a shot that
`x2video info` reads, keyframe shots included."""
import ast
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ADDON = ROOT / "packaging" / "blender" / "x2video_export"
ADDON_PASSES = ADDON / "passes.py"
PASSES = ROOT / "core" / "x2video" / "cycles" / "passes.py"
CLASSES = ROOT / "core" / "x2video" / "cycles" / "classes.py"
SHARED = ("AOVS", "PASS_FLAGS", "LIGHT_PASSES", "FILE_PASSES", "_TAG")
#: the functions the add-on and x2video.cycles.passes share, statement for statement
SHARED_CODE = ("configure_view_layer", "_principled_nodes", "_aov_name", "_aov_outputs", "wire_material")

bpy_missing = subprocess.run([sys.executable, "-c", "import importlib.util,sys; sys.exit(importlib.util.find_spec('bpy') is None)"], check=False).returncode
#: how each Blender runs a script: the `bpy` module (4.2, the cycles extra), and Blender itself (Debian's is 3.4)
RUNNERS = [pytest.param("bpy", marks=pytest.mark.skipif(bool(bpy_missing), reason="bpy is not installed: `pip install -e '.[cycles]'`")),
           pytest.param("blender", marks=pytest.mark.skipif(shutil.which("blender") is None, reason="no `blender` on PATH"))]


def run_blender(runner: str, script: Path, *args: str, timeout: int = 300) -> subprocess.CompletedProcess:
    """Run `script` with `args` (after "--" for Blender itself) in the `bpy` module or in `blender -b`."""
    if runner == "bpy":
        cmd = [sys.executable, str(script), *args]
    else:
        cmd = ["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python", str(script), "--", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)


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
    addon, passes = module_constants(ADDON_PASSES), module_constants(PASSES)
    for name in SHARED:
        assert name in passes, f"passes.py lost {name}"
        assert addon.get(name) == passes[name], f"{name}: the add-on's copy differs from x2video.cycles.passes"
    assert addon["KEEP_NOISY"] == ("DiffDir", "DiffInd")  # compositor_output's default keep_noisy
    assert module_constants(ADDON / "export.py")["GLOSSY_BELOW"] == module_constants(CLASSES)["GLOSSY_BELOW"]
    info = module_constants(ADDON / "__init__.py")["bl_info"]
    assert info["blender"] == (3, 4, 0) and info["category"] == "Render"
    tree = ast.parse((ADDON / "__init__.py").read_text())
    names = {n.name for n in tree.body if isinstance(n, (ast.ClassDef, ast.FunctionDef))}
    assert {"X2VIDEO_OT_export_shot", "X2VIDEO_PT_export", "register", "unregister"} <= names
    for path in ADDON.glob("*.py"):
        tree = ast.parse(path.read_text())
        imported = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))
                    for a in (n.names if isinstance(n, ast.Import) else [ast.alias(n.module or "")])}
        assert "x2video" not in imported, f"{path.name}: the add-on must be self-contained"


def function_bodies(path: Path) -> dict[str, tuple[list[str], str]]:
    """Top-level function name -> (its parameter names, its body without the docstring as ast.dump): comments,
    annotations and defaults do not count. Read without importing the module."""
    out = {}
    for fn in ast.parse(path.read_text()).body:
        if not isinstance(fn, ast.FunctionDef):
            continue
        body = fn.body[1:] if isinstance(fn.body[0], ast.Expr) and isinstance(fn.body[0].value, ast.Constant) else fn.body
        out[fn.name] = ([a.arg for a in fn.args.args], ast.dump(ast.Module(body=body, type_ignores=[])))
    return out


def test_addon_shares_passes_py_code():
    """The add-on's view-layer set-up and material wiring (the AOVs' sources, the removal of AOV outputs a material
    already had) are x2video.cycles.passes' functions statement for statement, parameters named alike. (Its
    compositor set-up differs on purpose: OpenImageDenoise's ACCURATE prefilter for a user's shot, the G-buffer
    frames' pass list; its pass table is the one compared above.)"""
    addon, passes = function_bodies(ADDON_PASSES), function_bodies(PASSES)
    for name in SHARED_CODE:
        assert name in passes and name in addon, f"{name} is missing from one copy"
        assert addon[name] == passes[name], f"{name}: the add-on's copy differs from x2video.cycles.passes"


def test_function_bodies_tells_a_changed_statement_apart(tmp_path):
    """The comparison above can fail: one changed constant in a body is a different body; a comment is not."""
    a, b, c = tmp_path / "a.py", tmp_path / "b.py", tmp_path / "c.py"
    a.write_text('def f(x):\n    """doc"""\n    return x + 1\n')
    b.write_text('def f(x):\n    """other doc"""\n    # a comment\n    return x + 1\n')
    c.write_text('def f(x):\n    return x + 2\n')
    assert function_bodies(a) == function_bodies(b) != function_bodies(c)

SCENE = textwrap.dedent("""
    import importlib.util, math, os, sys
    ARGS = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]  # addon folder, out folder, keyframe every
    devnull = os.open(os.devnull, os.O_WRONLY); os.dup2(devnull, 1)  # Blender's progress lines
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    spec = importlib.util.spec_from_file_location("x2video_export", os.path.join(ARGS[0], "__init__.py"), submodule_search_locations=[ARGS[0]])
    addon = importlib.util.module_from_spec(spec); sys.modules["x2video_export"] = addon; spec.loader.exec_module(addon); addon.register()
    every = int(ARGS[2]) if len(ARGS) > 2 else 0
    frames = 5 if every else 2
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples, scene.cycles.device = 4, "CPU"
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = (32, 24, 100) if every else (48, 32, 100)
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
    # a material with AOV outputs of its own under our names (as a user's AOV set-up has): they must not add to ours
    slab = obj("slab", bpy.ops.mesh.primitive_cube_add, {"Base Color": (0.2, 0.4, 0.6, 1), "Roughness": 0.3}, size=0.7, location=(-1.0, 0.2, 0.35))
    tree = slab.active_material.node_tree
    for name, value in (("basecolor", (0.2, 0.4, 0.6, 1)), ("roughness", 0.3), ("metallic", 0.0)):
        aov = tree.nodes.new("ShaderNodeOutputAOV")
        if hasattr(aov, "aov_name"):
            aov.aov_name = name
        else:
            aov.name = name
        aov.inputs["Color" if name == "basecolor" else "Value"].default_value = value
    # an emitter, for the emission channel
    bpy.ops.mesh.primitive_cube_add(size=0.5, location=(1.0, 0.3, 0.25))
    lamp = bpy.context.active_object; lamp.name = "lamp"
    mat = bpy.data.materials.new("lamp"); mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    em = nodes.new("ShaderNodeEmission"); em.inputs["Color"].default_value, em.inputs["Strength"].default_value = (1.0, 0.5, 0.25, 1), 2.0
    mat.node_tree.links.new(em.outputs["Emission"], nodes["Material Output"].inputs["Surface"])
    lamp.data.materials.append(mat)
    light = bpy.data.objects.new("light", bpy.data.lights.new("light", "AREA"))
    light.data.energy, light.data.size, light.location = 300, 2, (1, -1, 3)
    scene.collection.objects.link(light)
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam); scene.camera = cam
    for f, x in ((1, 0.0), (frames, 0.4)):
        cam.location, cam.rotation_euler = (x, -4, 2), (math.radians(65), 0, 0)
        cam.keyframe_insert("location", frame=f); cam.keyframe_insert("rotation_euler", frame=f)
    scene.frame_start, scene.frame_end = 1, frames
    res = bpy.ops.x2video.export_shot(directory=ARGS[1], frame_start=1, frame_end=frames, caption="a brass cube on a floor",
                                      keyframe_every=every)
    assert res == {"FINISHED"}, res
    addon.unregister()
""")


def export(tmp_path: Path, runner: str, keyframe_every: int = 0) -> Path:
    """The test scene exported through the add-on in `runner`'s Blender; returns the shot folder."""
    out = tmp_path / "shot"
    script = tmp_path / "scene.py"
    script.write_text(SCENE)
    proc = run_blender(runner, script, str(ADDON), str(out), str(keyframe_every))
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    return out


def info(out: Path, *flags: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "x2video", "info", str(out), *flags], capture_output=True, text=True, timeout=120,
                          check=False, env={**os.environ, "QT_QPA_PLATFORM": "offscreen"})


def object_id(out: Path, name: str) -> int:
    return int(next(k for k, v in json.loads((out / "shot.json").read_text())["objects"].items() if v == name))


@pytest.mark.slow
@pytest.mark.parametrize("runner", RUNNERS)
def test_addon_exports_a_shot_x2video_reads(tmp_path, runner):
    import numpy as np

    from x2video.io import load_shot

    out = export(tmp_path, runner)
    assert sorted(p.name for p in out.iterdir()) == ["cameras.json", "frame_0000.exr", "frame_0001.exr", "shot.json"]
    proc = info(out, "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout)
    assert report["frames"] == 2 and (report["width"], report["height"]) == (48, 32)
    assert {"albedo", "normal", "roughness", "metallic", "irradiance", "emission", "depth"} <= set(report["channels"]) and not report["dropped"]
    assert report["poses"] and report["caption"] == "a brass cube on a floor"
    shot = load_shot(out)
    assert shot.keyframes == (0, 1) and shot.info.rgb_frames is None
    cams = json.loads((out / "cameras.json").read_text())["frames"]
    assert np.allclose(np.asarray(cams[1]["cam_to_world"])[:3, 3], (0.4, -4, 2))  # matrix_world of frame 2
    assert cams[0]["fov_y_deg"] == pytest.approx(2 * np.degrees(np.arctan(36 / 2 / 50 / 1.5)), abs=1e-3)  # 50 mm, 36 mm sensor, 3:2
    fr = shot.frame(0)
    ids = fr["ids"][..., 0]
    meta = json.loads((out / "shot.json").read_text())
    cube, slab = object_id(out, "cube"), object_id(out, "slab")
    assert meta["extra"]["material_class"][str(cube)] == "metal"
    on_cube, on_slab = ids == cube, ids == slab
    assert on_cube.sum() >= 4 and on_slab.sum() >= 4
    # the metal's base colour reaches the basecolor AOV (DiffCol is black on metals), metallic is 1 there
    assert np.median(fr["metallic"][on_cube]) == pytest.approx(1.0, abs=0.01)
    assert np.allclose(np.median(fr["albedo"][on_cube], axis=0), (0.9, 0.7, 0.4), atol=0.02)
    # the slab's own AOV outputs were replaced, not summed with ours (Cycles adds outputs of one AOV: 2x before)
    assert np.allclose(np.median(fr["albedo"][on_slab], axis=0), (0.2, 0.4, 0.6), atol=0.02)
    assert np.median(fr["roughness"][on_slab]) == pytest.approx(0.3, abs=0.01)
    assert np.median(fr["metallic"][on_slab]) == pytest.approx(0.0, abs=0.01)
    on_lamp = ids == object_id(out, "lamp")
    assert on_lamp.any() and np.median(fr["emission"][on_lamp], axis=0) == pytest.approx((2.0, 1.0, 0.5), abs=0.02)
    assert np.median(fr["emission"][on_cube]) < 0.01
    # this Blender's denoiser is recorded; without one (Debian's 3.4) the export went on without it and says so
    if not meta["extra"]["denoiser_available"]:
        assert meta["extra"]["denoise"] is False and "OpenImageDenoise" in meta["extra"]["note"]


@pytest.mark.slow
@pytest.mark.parametrize("runner", RUNNERS)
def test_addon_keyframe_shot_loads_with_rgb_on_keyframes_only(tmp_path, runner):
    """keyframe_every=2 on 5 frames: full renders on 0, 2, 4, G-buffer passes (no Combined, no light passes) on 1 and 3;
    the loader names the keyframes, refuses rgb between them and reads emission and depth on every frame."""
    import numpy as np

    from x2video.io import load_shot
    from x2video.io.image import read_spec

    out = export(tmp_path, runner, keyframe_every=2)
    meta = json.loads((out / "shot.json").read_text())
    assert meta["keyframes"] == [0, 2, 4] and meta["extra"]["gbuffer_samples"] == 1
    cost = meta["extra"]["frame_seconds"]
    assert cost["keyframe"] > 0 and cost["gbuffer"] > 0 and len(cost["per_frame"]) == 5
    for t in range(5):
        passes = {c.split(".")[-2] for c in read_spec(out / f"frame_{t:04d}.exr").channelnames}
        assert ("Combined" in passes) == (t % 2 == 0), (t, sorted(passes))
        assert ("DiffDir" in passes) == (t % 2 == 0) and {"basecolor", "Normal", "Depth", "Emit", "Env", "IndexOB"} <= passes
    shot = load_shot(out)
    assert shot.keyframes == (0, 2, 4) and [shot.has_rgb(t) for t in range(5)] == [True, False, True, False, True]
    assert {"albedo", "normal", "roughness", "metallic", "ids", "depth", "emission", "rgb"} <= set(shot.channels)
    # the light passes (irradiance, and the Cycles colour/glossy passes the base stage's differences use) are
    # rendered on keyframes only: not the shot's channels, offered on the keyframes
    keyframe_only = set(shot.info.extra["keyframe_only"])
    assert keyframe_only == {"irradiance", "diffuse_color", "glossy", "glossy_color"}, keyframe_only
    assert not keyframe_only & set(shot.channels)
    assert shot.info.channel_frames == {c: (0, 2, 4) for c in keyframe_only}
    assert shot.has("irradiance", 2) and not shot.has("irradiance", 1) and shot.channel("irradiance", 2).max() > 0
    with pytest.raises(KeyError, match="frame 1 has no glossy"):
        shot.channel("glossy", 1)
    with pytest.raises(KeyError, match="frame 1 has no rgb"):
        shot.channel("rgb", 1)
    lamp, slab = object_id(out, "lamp"), object_id(out, "slab")
    for t in range(5):
        fr = shot.frame(t)
        assert ("rgb" in fr) == (t % 2 == 0)
        ids = fr["ids"][..., 0]
        assert np.allclose(np.median(fr["albedo"][ids == slab], axis=0), (0.2, 0.4, 0.6), atol=0.02), t
        assert np.median(fr["emission"][ids == lamp], axis=0) == pytest.approx((2.0, 1.0, 0.5), abs=0.02), t
        assert 2.0 < np.median(fr["depth"][ids == slab]) < 6.0, t  # metres from the camera 4-5 m away
    proc = info(out)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-2000:]
    assert "keyframes: 0, 2, 4 (3 of 5 frames carry rgb)" in proc.stdout


def _keyframes_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("x2video_export_keyframes", ADDON / "keyframes.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)  # bpy is imported only where a render runs
    return mod


def test_keyframe_choice_and_animation_runs():
    kf = _keyframes_module()
    assert kf.keyframe_list(17, every=8) == [0, 8, 16]
    assert kf.keyframe_list(20, every=8) == [0, 8, 16, 19]  # the last frame too: no frame after the last keyframe
    assert kf.keyframe_list(17, frames="0, 5 12") == [0, 5, 12] and kf.keyframe_list(17) is None
    with pytest.raises(ValueError, match=r"keyframes \[17\] lie outside the shot's frames 0..16"):
        kf.keyframe_list(17, frames="0, 17")
    with pytest.raises(ValueError, match="expected frame numbers"):
        kf.keyframe_list(17, frames="0, eight")
    # the frames between keyframes every 8 (0, 8, 16): 7 strided runs beat 2 consecutive ones only when longer
    assert kf.runs([1, 2, 3, 4, 5, 6, 7, 9, 10, 11, 12, 13, 14, 15]) == [(1, 7, 1), (9, 15, 1)]
    between = [t for t in range(65) if t % 4]  # keyframes every 4 over 65 frames: 48 frames, 3 runs of stride 4
    assert kf.runs(between) == [(1, 61, 4), (2, 62, 4), (3, 63, 4)]
    assert kf.runs([0, 2, 4, 6]) == [(0, 6, 2)] and kf.runs([3]) == [(3, 3, 1)] and kf.runs([]) == []
    assert kf.runs([1, 3, 4, 9]) == [(1, 1, 1), (3, 4, 1), (9, 9, 1)]
    covered = [f for a, b, step in kf.runs(between) for f in range(a, b + 1, step)]
    assert sorted(covered) == between
