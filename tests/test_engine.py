"""The diffusion tier's exported graphs (`x2video.model.engine`) against PyTorch, the reference: the video UNet with
every Hybrid Self-Attention branch active, the VAE decoder, the channel encoders, a whole render; the disk cache,
`Renderer.timing` and `Renderer.prepare`.

Measured differences (untrained tiny weights, alphas and LoRA perturbed so the reference and temporal branches
count): UNet max |diff| ~3e-6 on outputs of magnitude ~1-3 (ONNX Runtime and OpenVINO), decoder ~2e-5,
encoder ~3e-6; with the shipped weights (bench/render.py --parts): UNet 2.7e-6 (ORT) / 3.6e-6 (OpenVINO), decoder 2.4e-4,
encoder 1e-5, a whole LCM-2 render 2.6e-4 in linear RGB.
The bounds below leave a decade of room for other CPUs' kernels and no more."""
from __future__ import annotations

import os

import numpy as np
import pytest
import torch
from sampling_fake import FakeModel, make_shot

from x2video.model import engine as eng
from x2video.model.api import WindowInputs
from x2video.model.channel_encoder import ChannelEncoder
from x2video.model.hybrid_attention import mhf_gather
from x2video.model.pipeline import X2VideoModel
from x2video.model.unet import hybrid_processors
from x2video.render.events import FramesReady
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.render.timing import STAGES, StageTimes
from x2video.shot import ArrayShot

RUNTIMES = [r for r in ("onnx", "openvino") if eng.available(r)]
H, W = 32, 48  # pixels; latents 4x6 at the tiny preset's f=8


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))


@pytest.fixture(scope="module")
def model() -> X2VideoModel:
    m = X2VideoModel.untrained("tiny", seed=3)
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for proc in hybrid_processors(m.unet).values():  # every branch of Hybrid Self-Attention in play
            proc.alpha_r.fill_(0.3)
            proc.alpha_t.fill_(0.25)
            for p in (*proc.ref.parameters(), *proc.temp.parameters()):
                p.add_(0.05 * torch.randn(p.shape, generator=g))
    return m


def _window(model: X2VideoModel, n: int, mode: str, refs: tuple[int, ...], level: int = 1) -> tuple[torch.Tensor, WindowInputs]:
    g = torch.Generator().manual_seed(n + level)
    h, w = H // model.downsample, W // model.downsample
    x = torch.randn(n, 4, h, w, generator=g)
    inputs = WindowInputs(cond=torch.randn(n, model.cond_channels, h, w, generator=g), ref=torch.randn(n, 4, h, w, generator=g),
                          ref_positions=refs, mode=mode, level=level, text_global=torch.randn(1, 8, model.config.unet.cross_attention_dim, generator=g),
                          text_local=torch.zeros(0, 8, model.config.unet.cross_attention_dim), local_masks=torch.zeros(n, 0, H, W))
    return x, inputs


def test_mhf_gather_export_form_equals_views(monkeypatch) -> None:
    kv = torch.randn(2 * 5, 7, 8 * 3)  # (B*N, L, H*d)
    ref = mhf_gather(kv, 5, 8)
    monkeypatch.setattr(torch.onnx, "is_in_onnx_export", lambda: True)
    assert torch.equal(mhf_gather(kv, 5, 8), ref)


@pytest.mark.parametrize("runtime", RUNTIMES)
@pytest.mark.parametrize(("mode", "refs", "level"), [("key", (0,), 3), ("interp", (0, 4), 2)])
def test_unet_parity(model: X2VideoModel, runtime: str, mode: str, refs: tuple[int, ...], level: int) -> None:
    x, inputs = _window(model, 5, mode, refs, level)
    t = torch.tensor(601)
    model.set_engine("torch")
    want = model.predict_v(x, t, inputs)
    model.set_engine(runtime)
    got = model.predict_v(x, t, inputs)
    model.set_engine("torch")
    assert got.shape == want.shape
    assert float((got - want).abs().max()) < 1e-4, float((got - want).abs().max())
    assert float(want.abs().max()) > 0.1  # a real output, not zeros on both sides


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_unet_variants_differ(model: X2VideoModel, runtime: str) -> None:
    """Level and mode are baked into a graph: two variants must not share one (the alphas make them differ)."""
    x, a = _window(model, 5, "interp", (0, 4), 1)
    _, b = _window(model, 5, "interp", (0, 4), 2)
    b.cond, b.ref, b.text_global = a.cond, a.ref, a.text_global
    model.set_engine(runtime)
    va, vb = model.predict_v(x, torch.tensor(400), a), model.predict_v(x, torch.tensor(400), b)
    model.set_engine("torch")
    assert float((va - vb).abs().max()) > 1e-3


@pytest.mark.parametrize("runtime", RUNTIMES[-1:])  # the release does not depend on the runtime: auto's (OpenVINO when installed)
def test_unet_graphs_beyond_the_cap_are_released_least_recently_used_first(model: X2VideoModel, runtime: str) -> None:
    """A long shot's levels each bring UNet variants; the engine keeps `max_unet_graphs` of them and builds a released
    one again, with the same output, when it comes back."""
    parts = eng.CompiledParts(model, runtime, max_unet_graphs=2)
    calls = [_window(model, 5, "interp", (0, 4), level) for level in (1, 2, 3)]
    first = parts.unet(calls[0][0], torch.tensor(400), calls[0][1], lcm=False)
    parts.unet(calls[1][0], torch.tensor(400), calls[1][1], lcm=False)
    parts.unet(calls[0][0], torch.tensor(400), calls[0][1], lcm=False)  # level 1 used again: level 2 is now the oldest
    parts.unet(calls[2][0], torch.tensor(400), calls[2][1], lcm=False)
    held = parts.unet_graphs()
    assert len(held) == 2 and parts.released == 1
    assert [v[1] for v in held] == ["interp1", "interp3"]
    parts.unet(calls[1][0], torch.tensor(400), calls[1][1], lcm=False)  # built again from the disk cache
    assert [v[1] for v in parts.unet_graphs()] == ["interp3", "interp2"] and parts.released == 2
    again = parts.unet(calls[0][0], torch.tensor(400), calls[0][1], lcm=False)
    assert torch.equal(first, again)
    with pytest.raises(ValueError, match="max_unet_graphs"):
        eng.CompiledParts(model, runtime, max_unet_graphs=0)


def test_engine_threads_reach_the_graphs(monkeypatch) -> None:
    """`X2VideoModel.engine_threads` sets the graphs' threads (None: torch's count); the editor's factory gives them
    X2VIDEO_TORCH_THREADS, else every core."""
    pytest.importorskip("PySide6")
    from x2video_app._qt import render_controller as rc

    m = X2VideoModel.untrained("tiny", seed=5)
    for want, expected in ((None, torch.get_num_threads()), (3, 3)):
        m._parts.clear()
        m.engine_threads = want
        m.engine = "onnx"  # as set_engine would resolve it; nothing is built until a part runs
        assert m._compiled().threads == expected
    m.engine = "torch"
    monkeypatch.setattr(rc, "load_model", lambda choice: m)
    monkeypatch.delenv("X2VIDEO_TORCH_THREADS", raising=False)
    assert rc.RenderController._default_factory(None).model.engine_threads == (os.cpu_count() or 1)
    monkeypatch.setenv("X2VIDEO_TORCH_THREADS", "1")
    assert rc.RenderController._default_factory(None).model.engine_threads == 1


@pytest.mark.parametrize("runtime", RUNTIMES)
@pytest.mark.parametrize("distilled", [False, True])
def test_decoder_and_encoder_parity(runtime: str, distilled: bool) -> None:
    model = X2VideoModel.untrained("tiny", seed=4)
    if distilled:
        model.channel_encoder = ChannelEncoder.from_vae(model.vae, model.config.vae).eval()
    g = torch.Generator().manual_seed(1)
    z = torch.randn(3, 4, H // 8, W // 8, generator=g)
    imgs = [np.asarray(torch.rand(H, W, 3, generator=g) * 2 - 1) for _ in range(3)]
    want_rgb, want_z = model.decode(z), model._encode_channels(imgs)
    model.set_engine(runtime)
    got_rgb, got_z = model.decode(z), model._encode_channels(imgs)
    assert np.abs(got_rgb - want_rgb).max() < 1e-4
    assert float((got_z - want_z).abs().max()) < 1e-4
    assert float(want_z.abs().max()) > 0.01


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_render_parity_and_disk_cache(model: X2VideoModel, runtime: str) -> None:
    rng = np.random.default_rng(0)
    shot = ArrayShot({"albedo": rng.uniform(0, 1, (6, H, W, 3)), "irradiance": rng.uniform(0, 2, (6, H, W, 3)),
                      "roughness": rng.uniform(0, 1, (6, H, W, 1))}, fps=10.0, source="<test>")
    frames: dict[str, dict[int, np.ndarray]] = {}
    for name in ("torch", runtime):
        got: dict[int, np.ndarray] = {}
        r = Renderer(model)
        r.render(shot, None, RenderSettings(steps=2, engine=name, quality="diffusion"),
                 on_event=lambda e, got=got: got.update(e.frames) if isinstance(e, FramesReady) else None)
        assert r.engine == name
        frames[name] = got
    model.set_engine("torch")
    assert set(frames["torch"]) == set(frames[runtime]) == set(range(6))
    diff = max(np.abs(frames["torch"][f] - frames[runtime][f]).max() for f in range(6))
    assert diff < 1e-3, diff
    folder = eng.cache_dir()
    x, inputs = _window(model, 5, "key", (0,), 1)
    eng.CompiledParts(model, runtime, folder=folder).unet(x, torch.tensor(999), inputs, lcm=False)
    stamps = {p: p.stat().st_mtime_ns for p in folder.glob("*.onnx")}
    assert stamps  # exported once ...
    eng.CompiledParts(model, runtime, folder=folder).unet(x, torch.tensor(999), inputs, lcm=False)
    assert {p: p.stat().st_mtime_ns for p in folder.glob("*.onnx")} == stamps  # ... and read back, not written again


def test_resolve() -> None:
    assert eng.resolve("torch") == "torch"
    assert eng.resolve("auto", "cpu", torch.float16) == "torch"
    assert eng.resolve("auto", untrained=True) == "torch"
    assert eng.resolve("auto") in ("openvino", "onnx", "torch")
    with pytest.raises(ValueError, match="engine"):
        eng.resolve("tensorrt")
    with pytest.raises(ValueError, match="float32 models on the CPU"):
        eng.resolve("onnx", "cpu", torch.float16)
    for r in ("onnx", "openvino"):
        if not eng.available(r):
            with pytest.raises(ValueError, match="not installed"):
                eng.resolve(r)


def test_stage_times_split_a_render() -> None:
    r = Renderer(FakeModel())
    r.timing = StageTimes()
    r.render(make_shot(9), None, RenderSettings(steps=2, window=5))
    d = r.timing.as_dict(9)
    assert set(d["seconds"]) == set(STAGES)
    assert d["calls"]["unet"] >= 2 * 3 and d["calls"]["decode"] >= 3 and d["calls"]["encode"] >= 3 and d["calls"]["read"] >= 9
    assert d["calls"]["write"] >= 3
    assert sum(d["seconds"].values()) <= d["total"] + 1e-6
    r.timing = None
    r.render(make_shot(9), None, RenderSettings(steps=2, window=5))  # off: nothing timed, nothing fails


def test_prepare_fills_the_cache_and_a_render_reuses_it() -> None:
    model = FakeModel()
    r = Renderer(model)
    shot = make_shot(17)
    s = RenderSettings(steps=2, window=5, quality="diffusion")
    assert r.prepare(shot, s) == 17
    encoded = model.encoded_frames
    assert encoded == 17
    r.render(shot, None, s)
    assert model.encoded_frames == encoded and r.encode_seconds == 0.0  # nothing left to encode
    assert r.prepare(shot, s) == 0
    assert r.prepare(shot, RenderSettings(quality="formula")) == 0  # tier 0 encodes nothing


def test_a_render_cancels_a_prepare_in_progress() -> None:
    from x2video.render.events import CancelToken

    model = FakeModel()
    r = Renderer(model)
    token = CancelToken()
    r._preparing = token  # as while `prepare` runs in another thread
    r.render(make_shot(6), None, RenderSettings(steps=1, window=5))
    assert token.cancelled


def test_render_bench_memory_mode_reads_from_disk(tmp_path) -> None:
    """bench.render's 1,000-frame memory check (--preset --disk), at a toy size: the shot goes through an EXR folder
    and the loader, the frames through a sink, and the result records peak RSS."""
    import json

    from bench import render as bench_render

    out = tmp_path / "r.json"
    bench_render.main(["--preset", "fast", "--frames", "3", "--size", "32x24", "--disk", "--untrained", "--quality", "formula",
                       "--threads", "1", "--out", str(out)])
    run = next(iter(json.loads(out.read_text())["runs"].values()))
    assert run["frames"] == 3 and run["peak_rss_mb"] > 0 and run["size"] == [32, 24]
