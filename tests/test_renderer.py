"""Renderer with a fake RenderModel: event order, seeding, cache, reference plumbing, cancel, output sink."""
from __future__ import annotations

import dataclasses

import av
import numpy as np
import pytest
import torch
from sampling_fake import FakeModel, make_shot

from x2video.render.events import (
    CancelToken,
    FramesReady,
    RenderCancelled,
    RenderFailed,
    RenderFinished,
    RenderStarted,
    StepDone,
    WindowStarted,
)
from x2video.render.frames import FrameSink
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings, select_steps


def run(renderer: Renderer, shot, settings: RenderSettings, edits=None, cancel=None, extra=None) -> list:
    events: list = []

    def on_event(e) -> None:
        events.append(e)
        if extra is not None:
            extra(e)

    renderer.render(shot, edits, settings, on_event=on_event, cancel=cancel)
    return events


def frames_of(events: list) -> dict[int, np.ndarray]:
    out: dict[int, np.ndarray] = {}
    for e in events:
        if isinstance(e, FramesReady):
            assert not set(e.frames) & set(out)
            out.update(e.frames)
    return out


@pytest.mark.parametrize("scheme", ["recursive", "sequential"])
def test_event_order(scheme: str) -> None:
    shot = make_shot(18)
    settings = RenderSettings(steps=3, window=5, scheme=scheme, seams=False)  # the seam pass re-makes frames: its own test
    events = run(Renderer(FakeModel()), shot, settings)
    assert isinstance(events[0], RenderStarted) and isinstance(events[-1], RenderFinished)
    assert events[0].num_frames == 18 and events[-1].num_frames == 18
    # per window: WindowStarted, StepDone 1..steps, FramesReady (the first window: its first frame alone, then the rest)
    body = events[1:-1]
    starts = [i for i, e in enumerate(body) if isinstance(e, WindowStarted)] + [len(body)]
    assert len(starts) - 1 == events[0].num_windows and starts[0] == 0
    for n, (a, b) in enumerate(zip(starts, starts[1:])):
        w, steps, ready = body[a], body[a + 1 : a + 4], body[a + 4 : b]
        assert [(s.window, s.step, s.steps) for s in steps] == [(w.index, 1, 3), (w.index, 2, 3), (w.index, 3, 3)]
        assert len(ready) == (2 if n == 0 else 1) and all(isinstance(r, FramesReady) for r in ready)
        assert all(r.window == w.index and r.level == w.level and r.mode == w.mode for r in ready)
        assert [r.window_done for r in ready] == [False] * (len(ready) - 1) + [True]
        made = [f for r in ready for f in r.frames]
        assert set(made) <= set(w.frames) and len(made) == len(set(made)) and (n > 0 or len(ready[0].frames) == 1)
    ready = [e for e in events if isinstance(e, FramesReady)]
    levels = [e.level for e in ready]
    assert levels == sorted(levels, reverse=True)
    if scheme == "recursive":
        assert ready[0].mode == ready[1].mode == "key" and set(ready[0].frames) | set(ready[1].frames) == {0, 16, 17}
        assert all(e.mode == "interp" for e in ready[2:])
        assert events[0].levels == [3, 2, 1]
    frames = frames_of(events)
    assert sorted(frames) == list(range(18))
    assert all(f.shape == (16, 24, 3) and f.dtype == np.float32 for f in frames.values())


def test_same_seed_same_frames_other_seed_differs() -> None:
    shot = make_shot(9)
    s = RenderSettings(steps=2, window=5, seed=7)
    a = frames_of(run(Renderer(FakeModel()), shot, s))
    b = frames_of(run(Renderer(FakeModel()), shot, s))
    c = frames_of(run(Renderer(FakeModel()), shot, dataclasses.replace(s, seed=8)))
    assert all(np.array_equal(a[i], b[i]) for i in a)
    assert any(not np.array_equal(a[i], c[i]) for i in a)


def test_conditioning_encoded_once_per_frame_and_cached_across_renders() -> None:
    shot = make_shot(17)
    model = FakeModel()
    renderer = Renderer(model)
    run(renderer, shot, RenderSettings(steps=1, window=5))
    # level-2 frames appear in up to three windows; each is still encoded once
    assert model.encoded_frames == 17
    st = renderer.cache_stats()
    assert st.misses == 17 and st.hits == 8 and st.entries == 17
    assert renderer.encode_seconds > 0  # the time spent encoding is measured ...
    run(renderer, shot, RenderSettings(steps=1, window=5, seed=3))
    assert model.encoded_frames == 17 and renderer.cache_stats().hits == 8 + 25
    assert renderer.encode_seconds == 0.0  # ... and is zero on a re-render from a warm cache
    # changed content misses; another model's weights miss
    run(renderer, make_shot(17, seed=1), RenderSettings(steps=1, window=5))
    assert model.encoded_frames == 34
    other = Renderer(FakeModel(key="fake-v2"), cache=renderer.cache)
    run(other, shot, RenderSettings(steps=1, window=5))
    assert other.model.encoded_frames == 17


def test_a_renderer_that_does_not_retain_drops_each_frame_after_its_last_window() -> None:
    """`retain=False` (the CLI, farm workers): the same frames, each encoded once, and nothing left in the cache;
    during the render it holds no more than the frames still ahead."""
    shot = make_shot(33)
    kept, dropped = Renderer(FakeModel()), Renderer(FakeModel(), retain=False)
    held: list[int] = []

    def watch(e) -> None:
        if isinstance(e, FramesReady) and e.window_done:
            held.append(dropped.cache_stats().entries)

    def last(events: list) -> dict[int, np.ndarray]:  # the seam pass makes some frames twice: the later one counts
        return {f: img for e in events if isinstance(e, FramesReady) for f, img in e.frames.items()}

    a = last(run(kept, shot, RenderSettings(steps=1, window=5)))
    b = last(run(dropped, shot, RenderSettings(steps=1, window=5), extra=watch))
    assert a.keys() == b.keys() and all(np.array_equal(a[f], b[f]) for f in a)
    assert kept.model.encoded_frames == dropped.model.encoded_frames == 33  # nothing dropped too early
    assert kept.cache_stats().entries == 33 and dropped.cache_stats().entries == 0
    assert max(held) < 33


def test_interpolation_windows_read_the_produced_end_latents() -> None:
    shot = make_shot(17)
    model = FakeModel()
    renderer = Renderer(model)
    events = run(renderer, shot, RenderSettings(steps=1, window=5))
    order = [f for e in events if isinstance(e, FramesReady) for f in e.frames]
    produced = dict(zip(order, torch.cat(model.decoded)))  # frame -> its clean latent
    starts = [e for e in events if isinstance(e, WindowStarted)]
    assert len(model.windows) == len(starts)  # one predict call per window at 1 step
    for w, inputs in zip(starts, model.windows):
        if w.mode == "interp":
            assert inputs.ref_positions == (0, len(w.frames) - 1) and inputs.mode == "interp"
            assert torch.equal(inputs.ref[0], produced[w.frames[0]]) and torch.equal(inputs.ref[-1], produced[w.frames[-1]])
            assert inputs.ref[1:-1].abs().sum() == 0
        else:
            assert inputs.ref_positions == () and inputs.ref.abs().sum() == 0
    # latents are dropped after their last use: only the 5 keyframes are ever held, not 17
    assert renderer.peak_latents == 5


class _ResidualFake(FakeModel):
    """A residual model: the sample is the RGB latent minus an offset from the conditioning."""

    residual_prior = True

    prior = "shading"

    def sample_to_latents(self, x0: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        return x0 + 0.5 * cond


@pytest.mark.parametrize("model_cls", [FakeModel, _ResidualFake])
def test_replace_refs_holds_reference_positions_at_the_noised_reference(model_cls) -> None:
    """With replace_refs, every step after the first sees each produced reference at its latent
    (in sample space: minus the residual offset) noised with the window's own initial noise."""
    from x2video.sampling.samplers import alphas_cumprod

    ac = alphas_cumprod().float()
    shot = make_shot(17)
    for replace in (False, True):
        model = model_cls()
        events = run(Renderer(model), shot, RenderSettings(steps=4, window=5, replace_refs=replace, detail=False))
        order = [f for e in events if isinstance(e, FramesReady) for f in e.frames]
        produced = dict(zip(order, torch.cat(model.decoded)))  # frame -> its RGB latent
        starts = [e for e in events if isinstance(e, WindowStarted)]
        interp = [i for i, w in enumerate(starts) if w.mode == "interp"]
        assert interp
        matched = []
        for i in interp:
            w, calls, inputs = starts[i], model.x_t[4 * i : 4 * i + 4], model.windows[4 * i]
            pos = [0, len(w.frames) - 1]
            eps = calls[0][1][pos]  # t = 999: the initial noise itself
            rgb = torch.stack([produced[w.frames[p]] for p in pos])
            x0 = rgb - (0.5 * inputs.cond[pos] if model.residual_prior else 0)
            matched.append(all(torch.allclose(x[pos], ac[t].sqrt() * x0 + (1 - ac[t]).sqrt() * eps, atol=1e-5) for t, x in calls[1:]))
        assert all(matched) if replace else not any(matched)


def test_long_render_holds_few_latents() -> None:
    shot = make_shot(65, height=8, width=8)
    renderer = Renderer(FakeModel())
    run(renderer, shot, RenderSettings(steps=1, window=5))
    assert renderer.peak_latents == 17  # keyframes + level-2 frames, never level-1 frames


def test_frame_range_and_sequential_references() -> None:
    shot = make_shot(12)
    model = FakeModel()
    events = run(Renderer(model), shot, RenderSettings(steps=1, window=4, scheme="sequential", frames=(3, 10)))
    assert sorted(frames_of(events)) == list(range(3, 10))
    starts = [e for e in events if isinstance(e, WindowStarted)]
    assert [w.frames for w in starts] == [[3, 4, 5, 6], [6, 7, 8, 9]]
    assert model.windows[1].ref_positions == (0,) and model.windows[1].mode == "seq"


def test_presets_and_lcm() -> None:
    assert (select_steps(RenderSettings(preset="fast"), FakeModel()).sampler, select_steps(RenderSettings(preset="fast"), FakeModel()).steps) == ("ddim", 4)
    fast = select_steps(RenderSettings(preset="fast"), FakeModel(has_lcm=True))
    assert (fast.sampler, fast.steps) == ("lcm", 2)
    q = select_steps(RenderSettings(preset="quality", steps=3), FakeModel(has_lcm=True))
    assert (q.sampler, q.steps) == ("ddim", 20)
    events = run(Renderer(FakeModel(has_lcm=True)), make_shot(5), RenderSettings(preset="fast"))
    assert [e.steps for e in events if isinstance(e, StepDone)] == [2, 2]
    with pytest.raises(ValueError, match="LCM weights"):
        run(Renderer(FakeModel()), make_shot(5), RenderSettings(sampler="lcm", steps=2))


def test_bad_input_fails_with_event() -> None:
    with pytest.raises(ValueError, match="steps must be at least 1"):
        RenderSettings(steps=0)  # refused where the settings are made, whichever tier would run (issue 44)
    events: list = []
    shot = make_shot(5)
    with pytest.raises(ValueError, match="frame range"):
        Renderer(FakeModel()).render(shot, None, RenderSettings(steps=1, frames=(0, 9)), on_event=events.append)
    assert isinstance(events[-1], RenderFailed) and "frame range" in events[-1].error


@pytest.mark.parametrize("size", [(12, 24), (37, 53)])
def test_any_frame_size_is_padded_and_cropped_back(size) -> None:
    """A size that is not a multiple of the model's factor (8) is reflect-padded for the model and cropped back."""
    h, w = size
    shot = make_shot(5, height=h, width=w)
    model = FakeModel()
    events = run(Renderer(model), shot, RenderSettings(steps=1, window=5))
    frames = frames_of(events)
    assert sorted(frames) == list(range(5)) and all(f.shape == (h, w, 3) for f in frames.values())
    assert model.windows[0].cond.shape[-2:] == ((h + 7) // 8, (w + 7) // 8)  # the model saw the padded frame
    # reflect padding, not a resize: the model's input equals the frame inside, mirrored outside
    from x2video.conditioning.frame import plain_conditioning
    from x2video.conditioning.network import pad_conditioning

    c = pad_conditioning(plain_conditioning(shot, 0), (-h) % 8, (-w) % 8)
    a = c.channels["albedo"]
    assert a.shape[:2] == (h + (-h) % 8, w + (-w) % 8)
    np.testing.assert_array_equal(a[:h, :w], shot.channel("albedo", 0))
    np.testing.assert_array_equal(a[h, :w], shot.channel("albedo", 0)[h - 2])


def test_cancel_mid_render_keeps_finished_frames(tmp_path) -> None:
    shot = make_shot(17)
    model = FakeModel()
    token = CancelToken()
    model.on_predict = lambda n: token.cancel() if n == 3 * 2 + 1 else None  # first step of window 2
    out = tmp_path / "out.mp4"
    sink = FrameSink(out, fps=10)
    events = run(Renderer(model), shot, RenderSettings(steps=3, window=5), cancel=token, extra=sink)
    assert model.predict_calls == 7  # stopped within one step
    assert isinstance(events[-1], RenderCancelled)
    done = frames_of(events)
    assert events[-1].frames_done == sorted(done) == [0, 1, 2, 3, 4, 8, 12, 16]
    assert not any(isinstance(e, RenderFinished) for e in events)
    assert list(tmp_path.iterdir()) == []  # no partial output, no staging left


@pytest.mark.parametrize("name", ["out.mp4", "frames"])
def test_sink_writes_in_frame_order(tmp_path, name: str) -> None:
    shot = make_shot(9, height=16, width=24)
    out = tmp_path / name
    sink = FrameSink(out, fps=12, expected=list(range(9)))
    events = run(Renderer(FakeModel()), shot, RenderSettings(steps=1, window=5), extra=sink)
    frames = frames_of(events)
    assert sink.result == out and sorted(p.name for p in tmp_path.iterdir()) == [name]
    if name.endswith(".mp4"):
        with av.open(str(out)) as c:
            decoded = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
        assert len(decoded) == 9 and decoded[0].shape == (16, 24, 3)
        from x2video.channels import tonemap

        # frames arrive out of order (keyframes 0, 4, 8 first) but the video is in frame order
        for i in (1, 4, 7):
            want = tonemap(frames[i]) * 255
            errs = [np.abs(d.astype(np.float32) - want).mean() for d in decoded]
            assert int(np.argmin(errs)) == i
    else:
        import OpenImageIO as oiio

        files = sorted(p.name for p in out.iterdir())
        assert files == [f"{i:06d}.exr" for i in range(9)]
        buf = oiio.ImageBuf(str(out / "000005.exr"))
        assert buf.spec().channelnames == ("R", "G", "B")
        np.testing.assert_allclose(buf.get_pixels(oiio.FLOAT), frames[5], atol=2e-3)


def test_sink_rejects_incomplete(tmp_path) -> None:
    sink = FrameSink(tmp_path / "a.mp4", expected=[0, 1])
    sink.add(0, np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ValueError, match="missing frames \\[1\\]"):
        sink.finish()
    assert list(tmp_path.iterdir()) == []


def test_prompt_only_change_reencodes_nothing() -> None:
    from x2video.edits import Edits, Mask

    shot = make_shot(9)
    model = FakeModel()
    renderer = Renderer(model)
    edits = Edits(global_prompt="a warm evening")
    a = frames_of(run(renderer, shot, RenderSettings(steps=2), edits=edits))
    assert model.encoded_frames == 9
    edits.global_prompt = "cool daylight"
    mask = Mask()
    mask.paint(0, np.ones((16, 24), np.float32))
    mask.hold = True
    edits.masks["sofa"] = mask
    edits.local_prompts["sofa"] = "a red leather sofa"
    b = frames_of(run(renderer, shot, RenderSettings(steps=2), edits=edits))
    assert model.encoded_frames == 9, "a prompt-only change must not re-encode any frame"
    assert renderer.cache_stats().misses == 9
    assert all(not np.array_equal(a[i], b[i]) for i in a), "the prompt reached the model"
    assert model.encoded_prompts[-2:] == ["cool daylight", "a red leather sofa"]
    assert model.windows[-1].local_masks.shape == (5, 1, 16, 24)
    # an edit of the channels does re-encode exactly the frames it changes
    edits.dropped.add("normal")
    run(renderer, shot, RenderSettings(steps=1), edits=edits)
    assert model.encoded_frames == 18
    # identical content is encoded once (here: no albedo makes all frames of this shot alike)
    edits.dropped.add("albedo")
    run(renderer, shot, RenderSettings(steps=1), edits=edits)
    assert model.encoded_frames == 19


def test_reference_frame_conditions_the_keyframe_window() -> None:
    from x2video.edits import Edits, Reference

    base = make_shot(9)
    rgb = np.random.default_rng(5).uniform(0, 1, (9, 16, 24, 3)).astype(np.float32)
    from x2video.shot import ArrayShot

    shot = ArrayShot({**{n: np.stack([base.channel(n, t) for t in range(9)]) for n in base.channels}, "rgb": rgb})
    model = FakeModel()
    renderer = Renderer(model)
    events = run(renderer, shot, RenderSettings(steps=1, window=5), edits=Edits(reference=Reference(frame=4)))
    starts = [e for e in events if isinstance(e, WindowStarted)]
    assert starts[0].frames == [4, 5, 6, 7, 8] and starts[1].frames == [4, 3, 2, 1, 0]  # forwards and backwards from the reference
    first = model.windows[0]
    assert first.ref_positions == (0,) and torch.equal(first.ref[0], model.encode_image(rgb[4]))
    assert sorted(frames_of(events)) == list(range(9))


@pytest.mark.parametrize("name", ["out.mp4", "frames"])
def test_seam_pass_replaces_frames_and_the_sink_keeps_the_last(tmp_path, name: str) -> None:
    shot = make_shot(9, height=16, width=24)
    out = tmp_path / name
    sink = FrameSink(out, fps=12, expected=list(range(9)))
    settings = RenderSettings(steps=1, window=3, seams=True)  # keyframes 0, 4, 8; the pass at level 2 (stride 2)
    renderer = Renderer(FakeModel())
    events = run(renderer, shot, settings, extra=sink)
    assert events[0].num_frames == 9 and events[-1].num_frames == 9
    assert events[0].num_windows == len(renderer.plan(shot, settings)) == len(renderer.plan(shot, dataclasses.replace(settings, seams=False))) + 3
    last: dict[int, np.ndarray] = {}
    first: dict[int, np.ndarray] = {}
    seen: set[int] = set()
    for e in (e for e in events if isinstance(e, FramesReady)):
        first.update({f: v for f, v in e.frames.items() if f not in first})
        assert set(e.replaces) == set(e.frames) & seen, "replaces names exactly the frames that came before"
        seen |= set(e.frames)
        last.update(e.frames)
    assert {f for e in events if isinstance(e, FramesReady) for f in e.replaces} == {0, 4, 8}
    assert sink.result == out
    assert np.abs(first[4] - last[4]).max() > 0.01  # the seam window made frame 4 anew
    if name == "frames":
        import OpenImageIO as oiio

        np.testing.assert_allclose(oiio.ImageBuf(str(out / "000004.exr")).get_pixels(oiio.FLOAT), last[4], atol=2e-3)


def test_sink_refuses_a_replacement_of_nothing(tmp_path) -> None:
    sink = FrameSink(tmp_path / "a.mp4")
    with pytest.raises(ValueError, match="frame 3 arrived as a replacement"):
        sink.add(3, np.zeros((4, 4, 3), np.float32), replace=True)
    sink.add(2, np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ValueError, match="frame 2 arrived twice"):
        sink.add(2, np.zeros((4, 4, 3), np.float32))
    sink.abort()


def _initial_noise(model: FakeModel, events: list, steps: int) -> list[dict[int, torch.Tensor]]:
    """Per window, frame -> the window's initial noise at that frame's position (the t = 999 sample)."""
    starts = [e for e in events if isinstance(e, WindowStarted)]
    return [{f: model.x_t[steps * i][1][p] for p, f in enumerate(w.frames)} for i, w in enumerate(starts)]


def test_frame_noise_gives_a_frame_the_same_noise_in_every_window_and_sub_range() -> None:
    """noise='frame': a frame read as a reference is re-noised with the noise it was made from, and a
    re-render of a sub-range starts from the same noise; noise='window' (the default) does neither."""
    shot = make_shot(17)
    for noise in ("window", "frame"):
        model = FakeModel()
        events = run(Renderer(model), shot, RenderSettings(steps=2, window=5, noise=noise, detail=False))
        seen: dict[int, list[torch.Tensor]] = {}
        for per in _initial_noise(model, events, 2):
            for f, x in per.items():
                seen.setdefault(f, []).append(x)
        shared = [f for f, xs in seen.items() if len(xs) > 1]
        assert len(shared) == 5  # the keyframes 0, 4, 8, 12, 16 sit in their own and in interpolation windows
        same = [all(torch.equal(xs[0], x) for x in xs[1:]) for f, xs in seen.items() if f in shared]
        assert all(same) if noise == "frame" else not any(same)
        if noise == "frame":
            part = FakeModel()
            sub = run(Renderer(part), shot, RenderSettings(steps=2, window=5, noise=noise, frames=(8, 13), detail=False))
            for per in _initial_noise(part, sub, 2):
                for f, x in per.items():
                    assert torch.equal(x, seen[f][0])


def test_frame_noise_shares_the_requested_fraction_of_variance() -> None:
    from x2video.sampling.samplers import frame_noise

    x = frame_noise(3, [0, 1, 7], (4, 64, 64), 0.5).reshape(3, -1).double()
    assert torch.allclose(x.std(1), torch.ones(3, dtype=torch.float64), atol=0.03)  # each frame stays N(0, 1)
    corr = torch.corrcoef(x)
    assert torch.allclose(corr[~torch.eye(3, dtype=torch.bool)], torch.full((6,), 0.5, dtype=torch.float64), atol=0.03)
    indep = torch.corrcoef(frame_noise(3, [0, 1, 7], (4, 64, 64)).reshape(3, -1))
    assert indep[~torch.eye(3, dtype=torch.bool)].abs().max() < 0.03
    assert torch.equal(frame_noise(3, [7], (4, 8, 8), 0.5)[0], frame_noise(3, [0, 7], (4, 8, 8), 0.5)[1])  # per frame, not per call
    assert not torch.equal(frame_noise(3, [7], (4, 8, 8))[0], frame_noise(4, [7], (4, 8, 8))[0])


@pytest.mark.parametrize(("noise", "shared", "match"), [
    ("pink", 0.0, "unknown noise seeding 'pink'"),
    ("frame", 1.5, r"noise_shared must lie in \[0, 1\], got 1.5"),
    ("frame", -0.1, r"noise_shared must lie in \[0, 1\]"),
])
def test_bad_noise_settings_are_refused(noise: str, shared: float, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        run(Renderer(FakeModel()), make_shot(5), RenderSettings(steps=1, noise=noise, noise_shared=shared))  # type: ignore[arg-type]


def test_max_levels_caps_the_plan_the_renderer_runs() -> None:
    """K = 2 on 17 frames at N = 3: keyframes 2 apart in chained windows, then one interpolation level;
    every frame arrives once and a bad cap is refused before any window runs."""
    shot = make_shot(17, height=16, width=24)
    renderer = Renderer(FakeModel())
    settings = RenderSettings(steps=1, window=3, max_levels=2)
    windows = renderer.plan(shot, settings)
    assert max(w.level for w in windows) == 2 and [w.frames for w in windows if w.mode == "key"][:2] == [(0, 2, 4), (4, 6, 8)]
    assert max(w.level for w in renderer.plan(shot, dataclasses.replace(settings, max_levels=None))) == 4
    events = run(renderer, shot, settings)
    made = [f for e in events if isinstance(e, FramesReady) for f in e.frames]
    assert sorted(made) == list(range(17)) and events[0].num_windows == len(windows)
    with pytest.raises(ValueError, match="max_levels"):
        run(renderer, shot, dataclasses.replace(settings, max_levels=0))


def test_resample_repeats_steps_only_in_windows_with_references() -> None:
    """RePaint resampling (`RenderSettings.resample`): with DDIM-4 and r = 3, a window with references
    takes steps 2 and 3 three times (8 network passes), the keyframe window without one still 4; the
    same seed gives the same frames, LCM ignores it, and r < 1 is refused."""
    shot = make_shot(9, height=16, width=24)
    settings = RenderSettings(steps=4, window=5, resample=3)
    model = FakeModel()
    renderer = Renderer(model)
    windows = renderer.plan(shot, settings)
    events = run(renderer, shot, settings)
    passes = sum(8 if w.refs else 4 for w in windows)  # Known positions: frames earlier windows made
    assert any(w.refs for w in windows) and model.predict_calls == passes
    again = frames_of(run(Renderer(FakeModel()), shot, settings))
    assert all(np.array_equal(again[f], frames_of(events)[f]) for f in range(9))
    off = frames_of(run(Renderer(FakeModel()), shot, dataclasses.replace(settings, resample=1)))
    assert any(not np.allclose(off[f], again[f]) for f in range(9))  # the repeats change the generated frames
    lcm = FakeModel(has_lcm=True)
    run(Renderer(lcm), shot, dataclasses.replace(settings, sampler="lcm", steps=2))
    assert lcm.predict_calls == 2 * len(windows)
    with pytest.raises(ValueError, match="resample must be at least 1"):
        run(Renderer(FakeModel()), shot, dataclasses.replace(settings, resample=0))


@pytest.mark.parametrize("sampler", ["ddim", "lcm"])
def test_ref_dc_puts_inferred_frames_on_the_line_between_their_references(sampler: str) -> None:
    """`ref_dc` = 1 on a shot without irradiance (the lighting must be inferred): each generated frame of
    an interpolation window leaves with the per-channel latent mean linearly interpolated, by position,
    between its two references'; 0 leaves them off it, and frames that have their shading are left alone."""
    full = make_shot(17, height=16, width=24)
    dark = make_shot(17, height=16, width=24, irradiance=False)

    def latents_by_frame(shot, ref_dc: float) -> tuple[list, dict[int, torch.Tensor]]:
        model = FakeModel(has_lcm=True)
        renderer = Renderer(model)
        settings = RenderSettings(sampler=sampler, steps=3 if sampler == "ddim" else 2, window=5, ref_dc=ref_dc)  # type: ignore[arg-type]
        windows = renderer.plan(shot, settings)
        run(renderer, shot, settings)
        # decode calls in order (the first window's first frame is decoded alone)
        made = dict(zip([f for w in windows for f in w.generate], [z for dec in model.decoded for z in dec], strict=True))
        return windows, made

    def off_line(windows: list, made: dict[int, torch.Tensor]) -> float:
        worst = 0.0
        for w in windows:
            if w.mode != "interp":
                continue
            m0, m1 = (made[f].mean(dim=(-2, -1)) for f in w.refs)
            for p, f in zip(w.generate_positions, w.generate):
                lam = p / (len(w.frames) - 1)
                worst = max(worst, float(((1 - lam) * m0 + lam * m1 - made[f].mean(dim=(-2, -1))).abs().max()))
        return worst

    windows, made = latents_by_frame(dark, 1.0)
    assert any(w.mode == "interp" for w in windows) and off_line(windows, made) < 1e-5
    assert off_line(*latents_by_frame(dark, 0.0)) > 1e-2
    with_shading, without = latents_by_frame(full, 1.0)[1], latents_by_frame(full, 0.0)[1]
    assert all(torch.equal(with_shading[f], without[f]) for f in range(17))
    with pytest.raises(ValueError, match="ref_dc must lie in"):
        latents_by_frame(dark, 1.5)


def test_mean_anchor_moves_only_the_region_to_infer() -> None:
    """With an A|M|R-style region, the anchor moves the generated frames only inside it, to the
    interpolation of the references' means over their own regions; outside it nothing changes."""
    from x2video.sampling.planner import Window
    from x2video.sampling.samplers import mean_anchor

    g = torch.Generator().manual_seed(0)
    window = Window(frames=(0, 1, 2, 3, 4), generate=(1, 2, 3), refs=(0, 4), mode="interp", level=1)
    ref = torch.zeros(5, 4, 6, 8)
    ref[0], ref[4] = torch.randn(4, 6, 8, generator=g) + 1.0, torch.randn(4, 6, 8, generator=g) - 1.0
    regions = [torch.zeros(6, 8) for _ in range(5)]
    for p in range(5):
        regions[p][1:4, 2 + p // 2 : 5 + p // 2] = 1.0  # a moving 3x3 object
    offset = torch.randn(5, 4, 6, 8, generator=g) * 0.1
    fn = mean_anchor(window, 1.0, ref, offset, regions)
    x0 = torch.randn(5, 4, 6, 8, generator=g)
    out = fn(x0, 0)

    def mean_in(z, w):
        return (z * w).sum(dim=(-2, -1)) / w.sum()

    m0, m1 = mean_in(ref[0], regions[0]), mean_in(ref[4], regions[4])
    for p in (1, 2, 3):
        lam = p / 4
        assert torch.allclose(mean_in(out[p] + offset[p], regions[p]), (1 - lam) * m0 + lam * m1, atol=1e-5)
        assert torch.equal(out[p][:, regions[p] == 0], x0[p][:, regions[p] == 0])
    assert torch.equal(out[[0, 4]], x0[[0, 4]])  # reference positions are the Known's business
    assert mean_anchor(window, 1.0, ref, offset, [torch.zeros(6, 8)] * 5) is None  # nothing to infer
    assert mean_anchor(window, 0.0, ref, offset, regions) is None
    key = Window(frames=(0, 4, 8), generate=(0, 4, 8), refs=(), mode="key", level=2)
    assert mean_anchor(key, 1.0, ref[:3], offset[:3], regions[:3]) is None


def test_quality_formula_runs_no_network() -> None:
    from x2video.model.shading import classical_shading

    shot = make_shot(5, height=12, width=20)
    model = FakeModel()
    events = run(Renderer(model), shot, RenderSettings(quality="formula", frames=(1, 4)))
    frames = frames_of(events)
    assert sorted(frames) == [1, 2, 3] and model.predict_calls == 0 and model.encoded_frames == 0
    np.testing.assert_array_equal(frames[2], classical_shading(shot.frame(2)))
    assert isinstance(events[-1], RenderFinished)
