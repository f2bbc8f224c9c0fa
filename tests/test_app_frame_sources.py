"""The editor's record of where each frame comes from (x2video_app.state.frame_sources, RenderState.modes): the shot's
path-traced frames, frames filled from keyframes, and which tier edited each; the timeline's keyframe marks; and the
EXR export of a render over the base, in the input's units, the base bit for bit where no edit reached. Qt-free."""
from __future__ import annotations

import numpy as np
from test_base_render import BOX, H, T, W, box_edit

from x2video.base.difference import SPILL_MARGIN
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.shot import ArrayShot
from x2video_app.state.frame_sources import FILLED, PATH_TRACED, RENDERED, frame_sources, keyframe_marks, path_traced_frames
from x2video_app.state.render_state import RenderState


def room(scale: float = 1.0, rgb_frames: tuple[int, ...] | None = None) -> ArrayShot:
    """Five channels and an rgb that holds light they lack, its values half floats (as an EXR the add-on writes)."""
    rng = np.random.default_rng(5)
    albedo = rng.uniform(0.1, 0.9, (T, H, W, 3)).astype(np.float32)
    irr = np.broadcast_to(np.linspace(0.5, 2.0, W, dtype=np.float32)[None, None, :, None], (T, H, W, 3)).copy()
    normal = np.zeros((T, H, W, 3), np.float32)
    normal[..., 2] = 1
    rgb = albedo * irr + rng.uniform(0, 0.01, albedo.shape).astype(np.float32)
    rgb[:, 2:8, 2:12] += 3.0  # a window: light the channels do not hold
    arrays = {"albedo": albedo, "irradiance": irr * scale, "normal": normal, "rgb": rgb.astype(np.float16).astype(np.float32),
              "roughness": np.full((T, H, W, 1), 0.6, np.float32), "metallic": np.zeros((T, H, W, 1), np.float32)}
    shot = ArrayShot(arrays, irradiance_scale=scale)
    if rgb_frames is not None:
        from x2video.base.keyframes import KeyframeShot

        return KeyframeShot(shot, rgb_frames)
    return shot


def rendered(shot, settings: RenderSettings, edits=None) -> RenderState:
    """A RenderState fed a real render's events, begun as the editor's render controller begins it."""
    st = RenderState()
    st.begin(0, path_traced=path_traced_frames(shot, settings), irradiance_scale=shot.info.irradiance_scale)
    Renderer(None).render(shot, edits, settings, st.apply)
    assert st.status == "finished", st.error
    return st


def test_before_a_render_the_shots_path_traced_frames_show_and_its_keyframes_are_marked():
    idle = RenderState()
    full = room()
    src = frame_sources(full, RenderSettings(), idle)
    assert src.base and src.keyframes == () and src.kinds == {t: PATH_TRACED for t in range(T)}  # every frame: no marks
    keyed = room(rgb_frames=(0, 4))
    src = frame_sources(keyed, RenderSettings(), idle)
    assert src.keyframes == (0, 4) and src.kinds == {0: PATH_TRACED, 4: PATH_TRACED}  # the rest: to fill
    assert src.badge(2, rendered=False) == "not rendered yet" and src.badge(0, False) == "path-traced (not rendered yet)"
    assert keyframe_marks(full, RenderSettings(keyframes="every:2")) == (0, 2, 4)  # the setting names the keyframes
    assert frame_sources(full, RenderSettings(base="off"), idle).kinds == {}  # base off: nothing path-traced kept
    assert path_traced_frames(full, RenderSettings(keyframes="0,99")) == ()  # a bad setting: the render says why


def test_a_render_records_each_frames_source_and_the_tier_that_edited_it():
    shot = room(rgb_frames=(0, 4))
    e = box_edit()
    m = np.zeros((H, W), np.float32)
    m[BOX] = 1
    e.masks["sofa"].frames = {0: np.zeros((H, W), np.float32), 3: m}  # frames 0-2 unedited, 3-4 edited
    st = rendered(shot, RenderSettings(quality="formula"), e)
    assert st.modes == {0: "base", 1: "base", 2: "base", 3: "formula", 4: "formula"}
    src = frame_sources(shot, RenderSettings(), st)
    assert src.kinds == {0: PATH_TRACED, 1: FILLED, 2: FILLED, 3: "formula", 4: "formula"} and src.keyframes == (0, 4)
    assert src.badge(0, True) == "path-traced"
    assert src.badge(1, True) == "filled from its nearest keyframes"
    assert src.badge(3, True) == "filled from its nearest keyframes + tier 0's difference (formula)"
    assert src.badge(4, True) == "path-traced + tier 0's difference (formula)"
    off = rendered(shot, RenderSettings(quality="formula", base="off"), e)  # re-rendered from the channels: no base
    src = frame_sources(shot, RenderSettings(base="off"), off)
    assert not src.base and set(src.kinds.values()) == {RENDERED} and src.badge(3, True) == "rendered from the channels (formula)"
    assert off.exact == {}  # the float16 frames are what a render from the channels made


def test_export_of_an_albedo_edit_keeps_the_input_rgb_bit_for_bit_outside_it(tmp_path):
    from x2video.io.image import read_image
    from x2video.io.units import OutputUnits
    from x2video_app.state.exporter import export_exr

    shot = room(scale=0.37)  # irradiance normalised on load: the render's frames are in another exposure than the rgb
    st = rendered(shot, RenderSettings(quality="formula"), box_edit())
    assert set(st.modes.values()) == {"formula"} and sorted(st.exact) == list(range(T))
    list(export_exr(dict(st.frames), tmp_path / "exr", shot, units=OutputUnits.for_shot(shot), exact=st.exact))
    def exported(folder, t):  # the CLI's layout: 000000.exr, channels R, G, B in the input's units
        img = read_image(folder / f"{t:06d}.exr")
        return np.stack([img.channel(c) for c in "RGB"], -1)

    reach = np.zeros((H, W), bool)
    reach[BOX[0].start - SPILL_MARGIN - 1:BOX[0].stop + SPILL_MARGIN + 1, BOX[1].start - SPILL_MARGIN - 1:BOX[1].stop + SPILL_MARGIN + 1] = True
    for t in range(T):
        out, base = exported(tmp_path / "exr", t), shot.channel("rgb", t)
        np.testing.assert_array_equal(out[~reach], base[~reach])  # the input's units, the input's own pixels
        irr = shot.channel("irradiance", t)[BOX] / 0.37  # tier 0's difference, in the input's units
        want = base[BOX] + (np.array([0.9, 0.1, 0.1], np.float32) - shot.channel("albedo", t)[BOX]) * irr
        np.testing.assert_allclose(out[BOX], np.maximum(want, 0), rtol=2e-3, atol=2e-3)  # half floats on disk
    # the viewer's float16 frames, in the model's exposure, would not give the input back: why export takes `exact`
    list(export_exr(dict(st.frames), tmp_path / "lossy", shot, units=OutputUnits.for_shot(shot)))
    assert any(not np.array_equal(exported(tmp_path / "lossy", t)[~reach], shot.channel("rgb", t)[~reach]) for t in range(T))
