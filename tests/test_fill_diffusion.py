"""`RenderSettings.fill` 'diffusion' (the paper's Ref-Keyframe): a keyframe shot's frames between are made by the diffusion
tier, its plan anchored on the keyframes, every keyframe's path-traced frame a reference; keyframes come back exact."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from sampling_fake import FakeModel, make_shot

from x2video.base.stage import BASE
from x2video.edits import Edits
from x2video.edits.model import Reference
from x2video.io.units import OutputUnits
from x2video.render.events import FramesReady, RenderStarted
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.shot import ArrayShot

T, KEYS, SCALE = 9, (0, 4, 8), 0.5
#: N = 3: level 2 (stride 2) between adjacent keyframes, then level 1: windows with two keyframe ends, and with one
FILL = RenderSettings(fill="diffusion", keyframes="0,4,8", window=3, steps=2, seed=3)


def lit_shot() -> ArrayShot:
    """`make_shot` with a path-traced rgb (on every frame; `FILL.keyframes` keeps it on KEYS) and a normalised exposure."""
    base = make_shot(T)
    arrays = {n: np.stack([base.channel(n, t) for t in range(T)]) for n in base.channels}
    rng = np.random.default_rng(7)
    arrays["rgb"] = (arrays["albedo"] * 1.7 + rng.uniform(0, 0.2, arrays["albedo"].shape)).astype(np.float32)
    return ArrayShot(arrays, irradiance_scale=SCALE)


def render(model, shot, settings, edits=None):
    events: list = []
    Renderer(model).render(shot, edits, settings, events.append)
    frames: dict[int, np.ndarray] = {}
    for e in events:
        if isinstance(e, FramesReady):
            assert set(e.frames) & set(frames) <= set(e.replaces), "a frame delivered twice (not by the seam pass)"
            frames.update(e.frames)
    return events, frames


def test_the_plan_is_anchored_on_the_keyframes_and_reads_their_rgb():
    shot, model = lit_shot(), FakeModel()
    planned = Renderer(model).plan_render(shot, None, FILL)
    assert planned.tier == "diffusion" and "Ref-Keyframe" in planned.reason
    windows = list(planned.windows)
    assert not {f for w in windows for f in w.generate} & set(KEYS), "keyframes are read, never made"
    assert sorted({f for w in windows for f in w.generate} | set(KEYS)) == list(range(T))
    top = [w for w in windows if w.level == max(w.level for w in windows)]
    assert [(w.frames[0], w.frames[-1]) for w in top] == [(0, 4), (4, 8)]  # the widest windows' ends are the keyframes
    assert all(w.mode == "interp" and w.refs == (w.frames[0], w.frames[-1]) for w in windows)

    events, frames = render(model, shot, FILL)
    assert isinstance(events[0], RenderStarted) and events[0].num_frames == T and events[0].tier == "diffusion"
    assert sorted(frames) == list(range(T))
    # each window's predict calls (2 steps) carry, at a keyframe's position, the latent of that keyframe's rgb in the
    # model's exposure (rgb x irradiance_scale), as the network reads it
    assert len(model.windows) == 2 * len(windows)
    checked = 0
    for i, w in enumerate(windows):
        for call in model.windows[2 * i:2 * i + 2]:
            assert call.ref_positions == (0, len(w.frames) - 1)
            for pos, f in enumerate(w.frames):
                if f in KEYS:
                    want = model.encode_image(shot.channel("rgb", f) * np.float32(SCALE))
                    torch.testing.assert_close(call.ref[pos], want)
                    checked += 1
    assert checked == 2 * 2 * len(top) + 2 * (len(windows) - len(top))  # both ends on top, one end on level 1


def test_keyframes_come_back_bit_for_bit_and_the_fill_follows_them():
    shot = lit_shot()
    events, frames = render(FakeModel(), shot, FILL)
    units = OutputUnits.for_shot(shot)
    first = [e for e in events if isinstance(e, FramesReady)][0]
    assert first.mode == BASE and set(first.frames) == set(KEYS)  # the keyframes show before any window runs
    for t in KEYS:
        np.testing.assert_array_equal(units.scene(frames[t]), shot.channel("rgb", t))
    # the plain recursive plan (base off: no references, keyframes made too) gives other frames between
    _, plain = render(FakeModel(), shot, RenderSettings(base="off", window=3, steps=2, seed=3))
    for t in set(range(T)) - set(KEYS):
        assert np.isfinite(frames[t]).all()
        assert np.abs(frames[t] - plain[t]).max() > 1e-3, t


def test_render_windows_reads_the_keyframes_itself_and_matches_render():
    shot, model = lit_shot(), FakeModel()
    _, whole = render(model, shot, FILL)
    renderer = Renderer(FakeModel())
    windows = renderer.render_plan(shot, None, FILL)
    events: list = []
    renderer.render_windows(shot, None, FILL, list(range(len(windows))), {}, events.append)
    parts = {t: f for e in events if isinstance(e, FramesReady) for t, f in e.frames.items()}
    assert sorted(parts) == sorted(set(range(T)) - set(KEYS))
    for t, f in parts.items():
        np.testing.assert_allclose(f, whole[t], rtol=0, atol=1e-6)


def test_what_fill_diffusion_refuses_and_where_it_does_nothing():
    shot = lit_shot()
    e = Edits()
    e.reference = Reference(frame=0)
    with pytest.raises(ValueError, match="fill 'diffusion' renders a keyframe shot .* without edits"):
        render(FakeModel(), shot, FILL, e)
    with pytest.raises(ValueError, match="not quality 'formula'"):
        render(None, shot, RenderSettings(fill="diffusion", keyframes="0,8", quality="formula"))
    with pytest.raises(ValueError, match="needs a model"):
        render(None, shot, RenderSettings(fill="diffusion", keyframes="0,8"))
    with pytest.raises(ValueError, match="unknown fill 'learned'"):
        RenderSettings(fill="learned")
    # rgb on every frame: nothing to fill, the base as it is; fill 'classical': the reprojection, no tier
    events, frames = render(None, shot, RenderSettings(fill="diffusion"))
    assert events[0].tier == BASE and sorted(frames) == list(range(T))
    events, _ = render(None, shot, RenderSettings(keyframes="0,4,8"))
    assert events[0].tier == BASE


def test_the_cli_flag_reaches_the_settings():
    import argparse

    from x2video.fields import add_fields, from_args, to_flags

    p = argparse.ArgumentParser()
    add_fields(p, RenderSettings)
    s = from_args(RenderSettings, p.parse_args(["--fill", "diffusion", "--keyframes", "every:4"]))
    assert s.fill == "diffusion" and "--fill" in to_flags(RenderSettings, s)


def test_the_keyframe_bench_method_renders_the_clip_once_in_the_rgbs_units():
    from bench.keyframes import methods

    shot, model = lit_shot(), FakeModel()
    fill = methods(model=model, preset="quality")["diffusion"]
    cache: dict = {}
    got = fill(shot, [0, 4, 8], 2, cache)
    calls = model.predict_calls
    assert got.shape == (16, 24, 3) and np.isfinite(got).all()
    fill(shot, [0, 4, 8], 3, cache)
    assert model.predict_calls == calls  # the other frames come from the one render
    np.testing.assert_array_equal(cache["diffusion"][4], shot.channel("rgb", 4))  # a keyframe: its rgb, in its units
    _, frames = render(FakeModel(), shot, RenderSettings(fill="diffusion", keyframes="0,4,8", preset="quality"))
    np.testing.assert_allclose(got * SCALE, frames[2], rtol=1e-6)
    assert "diffusion" not in methods()


def test_the_cli_renders_a_keyframe_shot_with_fill_diffusion(tmp_path):
    from test_base_render import read_exr, room, write_shot

    from x2video.cli import main as cli
    from x2video.io.load import load_shot
    from x2video.io.sequence import find_frames

    write_shot(tmp_path / "shot", room(), frames_without_rgb=(1, 2, 3))
    shot = load_shot(tmp_path / "shot")
    assert shot.keyframes == (0, 4) and shot.info.irradiance_scale != 1.0
    args = ["render", str(tmp_path / "shot"), "--out", str(tmp_path / "out"), "--fill", "diffusion", "--untrained", "--steps", "1",
            "--engine", "torch"]
    assert cli(args) == 0
    files = find_frames(tmp_path / "out")
    assert len(files) == 5
    for t in (0, 4):
        np.testing.assert_array_equal(read_exr(files[t])[..., :3], shot.channel("rgb", t))
    assert all(np.isfinite(read_exr(files[t])).all() for t in (1, 2, 3))
