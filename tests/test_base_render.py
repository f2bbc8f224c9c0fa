"""The Renderer over a shot's base (x2video.base.stage, `RenderSettings.base` and `.keyframes`): the shot's own
path-traced frames come back bit for bit where no edit reaches, edits render as differences over them, a keyframe
shot's frames between are filled, and `--base off` renders as before the base existed."""
from __future__ import annotations

import numpy as np
import pytest
from test_base_fill import wall_shot

from x2video.base.difference import SPILL_MARGIN
from x2video.base.plan import base_caption
from x2video.base.stage import BASE
from x2video.cli import main as cli
from x2video.edits import Edits
from x2video.edits.masks import Mask
from x2video.edits.ops import AlbedoSet
from x2video.io.image import read_image
from x2video.io.load import load_shot
from x2video.io.sequence import find_frames
from x2video.io.shotdir import ShotWriter
from x2video.io.units import OutputUnits
from x2video.render.events import CancelToken, FramesReady, RenderCancelled, RenderFinished, RenderStarted
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.shot import ArrayShot

H, W, T = 32, 48, 5
BOX = (slice(10, 20), slice(14, 30))  # the edited object's pixels


def room(rgb: bool = True, scale: float = 1.0) -> ArrayShot:
    """Five channels and a path-traced rgb that holds light they lack (a bright 'window' the formula cannot make)."""
    rng = np.random.default_rng(3)
    albedo = rng.uniform(0.1, 0.9, (T, H, W, 3)).astype(np.float32)
    irr = np.broadcast_to(np.linspace(0.5, 2.0, W, dtype=np.float32)[None, None, :, None], (T, H, W, 3)).copy()
    normal = np.zeros((T, H, W, 3), np.float32)
    normal[..., 2] = 1
    arrays = {"albedo": albedo, "irradiance": irr * scale, "normal": normal,
              "roughness": np.full((T, H, W, 1), 0.6, np.float32), "metallic": np.zeros((T, H, W, 1), np.float32)}
    if rgb:
        shot_rgb = albedo * irr
        shot_rgb[:, 2:8, 2:12] += 3.0  # the window: light the five channels do not hold
        arrays["rgb"] = shot_rgb + rng.uniform(0, 0.01, shot_rgb.shape).astype(np.float32)  # path-tracing noise
    return ArrayShot(arrays, irradiance_scale=scale)


def render(shot, settings: RenderSettings, edits=None, renderer=None, cancel=None) -> tuple[list, dict[int, np.ndarray]]:
    events: list = []
    (renderer or Renderer(None)).render(shot, edits, settings, events.append, cancel)
    frames: dict[int, np.ndarray] = {}
    for e in events:
        if isinstance(e, FramesReady):
            assert not set(e.frames) & set(frames)
            frames.update(e.frames)
    return events, frames


def box_edit() -> Edits:
    e = Edits()
    m = np.zeros((H, W), np.float32)
    m[BOX] = 1
    e.masks["sofa"] = Mask(frames={0: m}, hold=True)
    e.ops.append(AlbedoSet(mask="sofa", color=(0.9, 0.1, 0.1)))
    return e


@pytest.mark.parametrize("scale", [1.0, 0.37])
def test_no_edits_return_the_shots_rgb_bit_for_bit_without_a_model(scale):
    shot = room(scale=scale)
    events, frames = render(shot, RenderSettings())  # quality auto, no model: no tier runs
    assert isinstance(events[0], RenderStarted) and events[0].tier == BASE and events[0].per_frame
    assert isinstance(events[-1], RenderFinished) and events[-1].num_frames == T
    units = OutputUnits.for_shot(shot)
    for t in range(T):
        np.testing.assert_array_equal(units.scene(frames[t]), shot.channel("rgb", t))
    assert Renderer(None).plan_render(shot, None, RenderSettings()).tier == BASE
    assert Renderer(None).plan_render(shot, Edits(), RenderSettings()).tier == BASE  # no operation: nothing to render


def test_an_albedo_edit_changes_only_what_it_reaches():
    shot = room(scale=0.5)
    _, frames = render(shot, RenderSettings(quality="formula"), box_edit())
    reach = np.zeros((H, W), bool)
    reach[BOX[0].start - SPILL_MARGIN - 1:BOX[0].stop + SPILL_MARGIN + 1, BOX[1].start - SPILL_MARGIN - 1:BOX[1].stop + SPILL_MARGIN + 1] = True
    units = OutputUnits.for_shot(shot)
    for t in range(T):
        out, base = units.scene(frames[t]), shot.channel("rgb", t)
        np.testing.assert_array_equal(out[~reach], base[~reach])  # the window and the rest: the base, bit for bit
        assert np.abs(out[BOX] - base[BOX]).max(-1).min() > 1e-3  # every pixel of the object changed
        # tier 0's difference: base + albedo' x irradiance - albedo x irradiance (in the shot's units)
        irr = shot.channel("irradiance", t)[BOX] / 0.5
        want = base[BOX] + (np.array([0.9, 0.1, 0.1], np.float32) - shot.channel("albedo", t)[BOX]) * irr
        np.testing.assert_allclose(out[BOX], np.maximum(want, 0), rtol=1e-5, atol=1e-5)


def test_a_roughness_edit_takes_tier_1s_difference_inside_its_reach_only():
    from test_tiers import with_net

    from x2video.edits.ops import ScalarOp

    shot, model = room(scale=0.5), with_net()
    e = box_edit()
    e.ops = [ScalarOp(mask="sofa", target_channel="roughness", value=0.9)]  # rougher: the reflection blurred
    events, frames = render(shot, RenderSettings(), e, Renderer(model))  # auto: tier 1 runs, its difference where gloss changed
    assert events[0].tier == "residual" and "over the shot's path-traced frames" in events[0].reason
    assert {ev.mode for ev in events if isinstance(ev, FramesReady)} == {"formula+residual"}
    reach = np.zeros((H, W), bool)
    reach[BOX[0].start - SPILL_MARGIN - 1:BOX[0].stop + SPILL_MARGIN + 1, BOX[1].start - SPILL_MARGIN - 1:BOX[1].stop + SPILL_MARGIN + 1] = True
    units = OutputUnits.for_shot(shot)
    for t in range(T):
        out, base = units.scene(frames[t]), shot.channel("rgb", t)
        np.testing.assert_array_equal(out[~reach], base[~reach])
        assert np.abs(out[BOX] - base[BOX]).max() > 1e-4  # the formula's difference is 0 here: only tier 1 changes it (a small random net)


def test_a_surface_made_glossier_keeps_the_formulas_difference_not_tier_1s_guess():
    """Sharper reflections show light no channel holds (`difference.sharpened`): tier 1's guess is not taken there, so
    a roughness-only edit towards gloss leaves the base as it was (the formula has no roughness), bit for bit."""
    from test_tiers import with_net

    from x2video.base.difference import edited_frame
    from x2video.conditioning.edited import apply_edits
    from x2video.conditioning.frame import plain_conditioning
    from x2video.edits.ops import ScalarOp

    shot, model = room(scale=0.5), with_net()
    e = box_edit()
    e.ops = [ScalarOp(mask="sofa", target_channel="roughness", value=0.05)]
    events, frames = render(shot, RenderSettings(), e, Renderer(model))
    assert {ev.mode for ev in events if isinstance(ev, FramesReady)} == {"formula"}
    units = OutputUnits.for_shot(shot)
    for t in range(T):
        np.testing.assert_array_equal(units.scene(frames[t]), shot.channel("rgb", t))
    # measured apart: `sharpen` takes tier 1's guess there after all, and it changes the object
    from x2video.tiers.residual import residual_frames

    base = shot.channel("rgb", 0).astype(np.float64) * 0.5
    out, mode = edited_frame(base, plain_conditioning(shot, 0), apply_edits(shot, e, 0), glossy_tier=True, sharpen=True,
                             residual=lambda e, o, where: tuple(residual_frames(model.residual_net, [e, o])))
    assert mode == "formula+residual" and np.abs(out[BOX] - base[BOX]).max() > 1e-4


def test_base_off_renders_as_before():
    with_rgb, without = room(), room(rgb=False)
    events, off = render(with_rgb, RenderSettings(quality="formula", base="off"))
    assert events[0].tier == "formula"
    _, before = render(without, RenderSettings(quality="formula"))  # a shot without rgb has no base: as before
    for t in range(T):
        np.testing.assert_array_equal(off[t], before[t])
        assert not np.array_equal(OutputUnits.for_shot(with_rgb).scene(off[t]), with_rgb.channel("rgb", t))
    with pytest.raises(ValueError, match="needs a model"):  # no base to stand in: auto needs its model, as before
        render(with_rgb, RenderSettings(base="off"))


def test_keyframes_render_every_frame_keyframes_exact_and_the_rest_filled():
    xs = [0.05 * i for i in range(9)]
    shot = wall_shot(xs)
    events, frames = render(shot, RenderSettings(keyframes="every:4"))
    assert sorted(frames) == list(range(9)) and "3 keyframes of 9 frames" in events[0].reason
    for t in range(9):
        rgb = shot.channel("rgb", t)
        if t in (0, 4, 8):
            np.testing.assert_array_equal(frames[t].astype(np.float32), rgb)
        else:
            assert np.isfinite(frames[t]).all()
            assert 10 * np.log10(1.5**2 / np.mean((frames[t] - rgb) ** 2)) > 35  # reprojected from the keyframes
    with pytest.raises(ValueError, match="--keyframes: frame 12 is outside the shot's 9 frames"):
        render(shot, RenderSettings(keyframes="0,12"))


def test_cancel_between_batches_of_base_frames():
    token = CancelToken()

    def cancel_after_first(e) -> None:
        if isinstance(e, FramesReady):
            token.cancel()

    events: list = []
    Renderer(None).render(room(), None, RenderSettings(), lambda e: (events.append(e), cancel_after_first(e)), token)
    assert isinstance(events[-1], RenderCancelled) and events[-1].frames_done == [0]


def read_exr(path) -> np.ndarray:
    img = read_image(path)
    return np.stack([img.planes[c] for c in "RGB"], -1).astype(np.float32)


def write_shot(folder, shot, frames_without_rgb=()) -> None:
    with ShotWriter(folder, shot.info, irradiance_normalized=False) as w:
        for t in range(shot.num_frames):
            w.write_frame(t, shot.frame(t))
    for t in frames_without_rgb:
        (folder / "rgb" / f"{t:06d}.exr").unlink()


def test_cli_writes_the_shots_rgb_in_its_units(tmp_path):
    write_shot(tmp_path / "shot", room())
    shot = load_shot(tmp_path / "shot")
    assert shot.info.irradiance_scale != 1.0  # measured by the loader: the frames go through a real exposure
    assert cli(["render", str(tmp_path / "shot"), "--out", str(tmp_path / "out")]) == 0  # no weights needed
    files = find_frames(tmp_path / "out")
    assert len(files) == T
    for t, f in enumerate(files):
        np.testing.assert_array_equal(read_exr(f)[..., :3], shot.channel("rgb", t))


def test_cli_renders_a_keyframe_shot_with_gaps(tmp_path):
    write_shot(tmp_path / "shot", wall_shot([0.05 * i for i in range(5)]), frames_without_rgb=(1, 2, 3))
    assert load_shot(tmp_path / "shot").keyframes == (0, 4)
    assert cli(["render", str(tmp_path / "shot"), "--out", str(tmp_path / "out")]) == 0
    frames = [read_exr(f) for f in find_frames(tmp_path / "out")]
    assert len(frames) == 5 and all(np.isfinite(f).all() for f in frames)


def test_cli_flags_parse_and_bad_values_name_the_flag(tmp_path, capsys):
    from x2video.cli import build_parser
    from x2video.fields import from_args

    args = build_parser().parse_args(["render", "s", "--out", "o", "--base", "off", "--keyframes", "every:4"])
    s = from_args(RenderSettings, args)
    assert (s.base, s.keyframes) == ("off", "every:4")
    assert from_args(RenderSettings, build_parser().parse_args(["render", "s", "--out", "o"])).base == "auto"
    with pytest.raises(SystemExit):
        build_parser().parse_args(["render", "s", "--out", "o", "--base", "on"])
    assert "--base" in capsys.readouterr().err
    write_shot(tmp_path / "shot", room())
    for bad, msg in [("every:x", "--keyframes 'every:x'"), ("1,a", "--keyframes '1,a'"), ("0,40", "--keyframes: frame 40 is outside")]:
        assert cli(["render", str(tmp_path / "shot"), "--out", str(tmp_path / "o"), "--keyframes", bad]) == 2
        assert msg in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown base 'on'"):
        RenderSettings(base="on")  # type: ignore[arg-type]


def test_base_caption_says_what_the_base_is():
    assert base_caption(room(), RenderSettings()) == "Base: the shot's path-traced frames (rgb on every frame)"
    assert "2 keyframes of 5 frames" in base_caption(wall_shot([0.0] * 5), RenderSettings(keyframes="0,4"))
    assert "off" in base_caption(room(), RenderSettings(base="off"))
    assert base_caption(room(rgb=False), RenderSettings()) == ""


def test_editor_document_says_its_shot_is_the_base():
    from x2video_app.state.document import Document

    doc = Document()
    assert doc.base_caption == ""
    doc.set_shot(room(), None)
    assert doc.base_caption == "Base: the shot's path-traced frames (rgb on every frame)"
    doc.set_shot(room(rgb=False), None)
    assert doc.base_caption == ""



def test_a_keyframe_shot_fills_the_frames_nearest_a_keyframe_first():
    from x2video.base.keyframes import only_keyframes
    from x2video.base.plan import base_order

    shot = wall_shot([0.05 * i for i in range(9)])
    assert base_order(shot, 0, 9) == [0, 8, 4, 2, 6, 1, 3, 5, 7]  # rgb on every frame: coarse to fine, as before
    keyed = only_keyframes(shot, "0,8")
    assert keyed.keyframes == (0, 8)
    order = base_order(keyed, 0, 9)
    dist = [min(abs(t - 0), abs(t - 8)) for t in order]
    assert order[:2] == [0, 8] and dist == sorted(dist) and sorted(order) == list(range(9))
    assert base_order(keyed, 2, 6) == [2, 3, 5, 4]  # a range without a keyframe: by distance to the shot's keyframes
    events, frames = render(shot, RenderSettings(keyframes="0,8"))
    arrived = [t for e in events if isinstance(e, FramesReady) for t in e.frames]
    assert arrived == order and sorted(frames) == list(range(9))


def test_each_event_carries_one_mode_for_all_its_frames():
    shot = room()
    e = box_edit()
    m = np.zeros((H, W), np.float32)
    m[BOX] = 1
    e.masks["sofa"].frames = {0: m, 1: m, 2: np.zeros((H, W), np.float32)}  # frames 2.. the mask is empty: no edit
    e.masks["sofa"].hold = True
    events, frames = render(shot, RenderSettings(quality="formula"), e)
    modes = {t: ev.mode for ev in events if isinstance(ev, FramesReady) for t in ev.frames}
    assert modes == {0: "formula", 1: "formula", 2: BASE, 3: BASE, 4: BASE}
    done = [ev for ev in events if isinstance(ev, FramesReady) and ev.window_done]
    assert len(done) == len({ev.window for ev in events if isinstance(ev, FramesReady)})  # each batch ends once


def test_a_live_preview_fills_a_frame_between_keyframes_once(monkeypatch):
    """A retaining Renderer (the editor's) keeps the shot's base frames across renders: dragging a slider on a frame
    between keyframes fills it once (the fill does not depend on the edits), with the pixels a fresh render makes."""
    from x2video.base import fill
    from x2video.render.live import render_frame

    shot = wall_shot([0.05 * i for i in range(9)])
    h, w = shot.size
    filled: list[int] = []
    real = fill.fill_frame
    monkeypatch.setattr(fill, "fill_frame", lambda s, t, *a, **k: filled.append(t) or real(s, t, *a, **k))

    def recolour(red: float) -> Edits:
        e = Edits()
        m = np.zeros((h, w), np.float32)
        m[8:20, 10:30] = 1
        e.masks["wall"] = Mask(frames={0: m}, hold=True)
        e.ops.append(AlbedoSet(mask="wall", color=(red, 0.2, 0.1)))
        return e

    live, settings = Renderer(None), RenderSettings(quality="formula", keyframes="0,8")
    images = [render_frame(live, shot, recolour(red), settings, 4).image for red in (0.9, 0.5)]
    assert filled == [4]  # the second move reused frame 4's fill
    fresh = render_frame(Renderer(None, retain=False), shot, recolour(0.5), settings, 4)
    assert filled == [4, 4]  # a one-off render keeps nothing
    np.testing.assert_array_equal(images[1], fresh.image)
    assert float(np.abs(images[0] - images[1]).max()) > 0.01
    render_frame(live, wall_shot([0.05 * i for i in range(9)]), recolour(0.5), settings, 4)
    assert filled == [4, 4, 4]  # another shot: its own fill
